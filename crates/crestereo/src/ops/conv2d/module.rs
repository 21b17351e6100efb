//! The network's convolution module. Every convolution of the model is one of these, so each
//! call goes through the kernel dispatch: a new module cannot miss the fast path by calling a
//! Burn convolution directly. Field names and record layout are those of Burn's `Conv2d`
//! (reference state dicts and saved records load unchanged).

use burn::module::{Module, Param};
use burn::nn::PaddingConfig2d;
use burn::prelude::*;

use crate::ops::dispatch::{Kernels, kernels_f32};

/// Configuration of a [`Conv2d`]: PyTorch's `nn.Conv2d` initialisation (as Burn's).
#[derive(Config, Debug)]
pub struct Conv2dConfig {
    /// Input and output channels.
    pub channels: [usize; 2],
    pub kernel_size: [usize; 2],
    #[config(default = "[1, 1]")]
    pub stride: [usize; 2],
    #[config(default = "[1, 1]")]
    pub dilation: [usize; 2],
    #[config(default = "1")]
    pub groups: usize,
    #[config(default = "PaddingConfig2d::Valid")]
    pub padding: PaddingConfig2d,
    #[config(default = true)]
    pub bias: bool,
}

/// A 2-D convolution whose forward is chosen by [`crate::ops::dispatch`]: the Flex kernels of
/// [`super`] where they apply, Burn's convolution ([`super::composed::conv2d`]) elsewhere.
#[derive(Module, Debug)]
pub struct Conv2d<B: Backend> {
    /// (C_out, C_in / groups, kh, kw).
    pub weight: Param<Tensor<B, 4>>,
    pub bias: Option<Param<Tensor<B, 1>>>,
    pub stride: [usize; 2],
    pub kernel_size: [usize; 2],
    pub dilation: [usize; 2],
    pub groups: usize,
    pub padding: PaddingConfig2d,
}

impl Conv2dConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> Conv2d<B> {
        // Burn's initialiser (PyTorch's Kaiming-uniform weights and fan-in bias), then its
        // parameters moved into this module.
        let made = burn::nn::conv::Conv2dConfig::new(self.channels, self.kernel_size)
            .with_stride(self.stride)
            .with_dilation(self.dilation)
            .with_groups(self.groups)
            .with_padding(self.padding.clone())
            .with_bias(self.bias)
            .init(device);
        Conv2d {
            weight: made.weight,
            bias: made.bias,
            stride: made.stride,
            kernel_size: made.kernel_size,
            dilation: made.dilation,
            groups: made.groups,
            padding: made.padding,
        }
    }
}

impl<B: Backend> Conv2d<B> {
    /// The convolution of `x` (N, C_in, H, W): a kernel where one applies; on a CubeCL backend
    /// at the default float32 precision every groups-1 convolution, and on wgpu at any
    /// precision the stride-1 ones, as one matrix product over the unfolded input
    /// ([`Self::forward_by_matmul`]); else Burn's convolution (autotuned on CubeCL backends,
    /// TF32 on NVIDIA tensor cores: `--precision tf32`).
    pub fn forward(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let w = self.weight.val();
        if self.groups == 1 && crate::ops::matmul::runs_fixed_f32(&[&x, &w]) {
            return self.forward_by_matmul(x);
        }
        match kernels_f32(&[&x, &w]) {
            choice @ (Kernels::Flex | Kernels::AutodiffFlex) if super::kernels_apply(self) => {
                super::kernel_forward(self, x, choice)
            }
            #[cfg(feature = "wgpu")]
            Kernels::Wgpu | Kernels::AutodiffWgpu if self.stride == [1, 1] && self.groups == 1 => {
                self.forward_by_matmul(x)
            }
            _ => super::composed::conv2d(self, x),
        }
    }

    /// A groups-1 convolution as one matrix product over the input unfolded from shifted (and
    /// stepped) slices (Burn tensor ops; any backend). Panics on other groups.
    pub fn forward_by_matmul(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        assert!(self.groups == 1, "forward_by_matmul: groups 1 only");
        let padding = self.symmetric_padding().expect("symmetric padding");
        let dtype = x.dtype();
        let weight = crate::ops::float_like(self.weight.val(), dtype);
        let bias = self
            .bias
            .as_ref()
            .map(|b| crate::ops::float_like(b.val(), dtype));
        super::by_matmul::conv2d_by_matmul(x, weight, bias, padding, self.stride, self.dilation)
    }

    /// (top = bottom, left = right) of an explicit symmetric or valid padding.
    pub(crate) fn symmetric_padding(&self) -> Option<[usize; 2]> {
        match self.padding {
            PaddingConfig2d::Explicit(top, left, bottom, right)
                if top == bottom && left == right =>
            {
                Some([top, left])
            }
            PaddingConfig2d::Valid => Some([0, 0]),
            _ => None,
        }
    }
}

impl<B: Backend> Conv2d<B> {
    /// This convolution as an ONNX `Conv` node (weights and bias as initializers, shared by
    /// every call).
    pub fn emit(
        &self,
        g: &mut crate::export::onnx::Graph,
        x: &crate::export::onnx::Value,
    ) -> crate::export::onnx::Value {
        let [top, left] = self.symmetric_padding().unwrap_or_else(|| {
            panic!(
                "convolution padding {:?} is not symmetric explicit or valid",
                self.padding
            )
        });
        let weight = g.param(&self.weight);
        let bias = self.bias.as_ref().map(|b| g.param(b));
        g.conv(
            x,
            &weight,
            bias.as_ref(),
            self.stride,
            [top, left, top, left],
            self.dilation,
            self.groups,
        )
    }
}
