//! Feature encoder `fnet`: RAFT-style BasicEncoder with instance normalisation (no affine).

use burn::nn::PaddingConfig2d;
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::export::onnx::{Graph, Value};
use crate::ops::conv2d::{Conv2d, Conv2dConfig};
use crate::ops::norm::instance_norm_act;

/// PyTorch `nn.InstanceNorm2d(affine=False, track_running_stats=False)`: per sample and channel,
/// biased variance over H×W.
pub fn instance_norm<B: Backend>(x: Tensor<B, 4>, eps: f64) -> Tensor<B, 4> {
    crate::ops::norm::instance_norm_act(x, eps, false)
}

/// Whether the parameter of this (reference) name is a bias that an instance normalisation
/// subtracts again: `fnet.conv1` and every residual block's `conv1`, `conv2` and `downsample.0`
/// feed an [`instance_norm`], which removes each channel's mean, so no output depends on their
/// biases and the gradient a loss gives them is rounding noise (Adam then moves them by about
/// the learning rate in a random direction). Comparisons of trained weights leave them out.
pub fn bias_cancelled_by_instance_norm(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("fnet.") else {
        return false;
    };
    rest == "conv1.bias"
        || (rest.starts_with("layer")
            && [".conv1.bias", ".conv2.bias", ".downsample.0.bias"]
                .iter()
                .any(|end| rest.ends_with(end)))
}

/// A PyTorch-style `nn.Conv2d(cin, cout, k, stride, padding)` with symmetric zero padding.
pub(crate) fn conv_cfg(
    cin: usize,
    cout: usize,
    k: [usize; 2],
    stride: usize,
    pad: [usize; 2],
) -> Conv2dConfig {
    Conv2dConfig::new([cin, cout], k)
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(pad[0], pad[1], pad[0], pad[1]))
        .with_bias(true)
}

#[derive(Config, Debug)]
pub struct ResidualBlockConfig {
    pub in_planes: usize,
    pub planes: usize,
    #[config(default = 1)]
    pub stride: usize,
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

/// Two 3×3 conv + InstanceNorm + ReLU, with a 1×1 conv + InstanceNorm shortcut (`downsample`)
/// that the reference applies even when the shapes already match.
#[derive(Module, Debug)]
pub struct ResidualBlock<B: Backend> {
    pub conv1: Conv2d<B>,
    pub conv2: Conv2d<B>,
    pub downsample: Conv2d<B>,
    pub norm_eps: f64,
}

impl ResidualBlockConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> ResidualBlock<B> {
        ResidualBlock {
            conv1: conv_cfg(self.in_planes, self.planes, [3, 3], self.stride, [1, 1]).init(device),
            conv2: conv_cfg(self.planes, self.planes, [3, 3], 1, [1, 1]).init(device),
            downsample: conv_cfg(self.in_planes, self.planes, [1, 1], self.stride, [0, 0])
                .init(device),
            norm_eps: self.norm_eps,
        }
    }
}

impl<B: Backend> ResidualBlock<B> {
    pub fn forward(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let eps = self.norm_eps;
        let y = instance_norm_act(self.conv1.forward(x.clone()), eps, true);
        let y = instance_norm_act(self.conv2.forward(y), eps, true);
        let x = instance_norm(self.downsample.forward(x), eps);
        relu(x + y)
    }
}

#[derive(Config, Debug)]
pub struct BasicEncoderConfig {
    #[config(default = 256)]
    pub output_dim: usize,
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

/// 7×7/2 conv → stages 64 (stride 1), 96 (stride 2), 128 (stride 1) → 1×1 conv to `output_dim`.
/// Output at 1/4 of the input resolution.
#[derive(Module, Debug)]
pub struct BasicEncoder<B: Backend> {
    pub conv1: Conv2d<B>,
    pub layer1: Vec<ResidualBlock<B>>,
    pub layer2: Vec<ResidualBlock<B>>,
    pub layer3: Vec<ResidualBlock<B>>,
    pub conv2: Conv2d<B>,
    pub norm_eps: f64,
}

impl BasicEncoderConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> BasicEncoder<B> {
        let stage = |cin: usize, cout: usize, stride: usize| -> Vec<ResidualBlock<B>> {
            vec![
                ResidualBlockConfig::new(cin, cout)
                    .with_stride(stride)
                    .with_norm_eps(self.norm_eps)
                    .init(device),
                ResidualBlockConfig::new(cout, cout)
                    .with_norm_eps(self.norm_eps)
                    .init(device),
            ]
        };
        BasicEncoder {
            conv1: conv_cfg(3, 64, [7, 7], 2, [3, 3]).init(device),
            layer1: stage(64, 64, 1),
            layer2: stage(64, 96, 2),
            layer3: stage(96, 128, 1),
            conv2: conv_cfg(128, self.output_dim, [1, 1], 1, [0, 0]).init(device),
            norm_eps: self.norm_eps,
        }
    }
}

impl<B: Backend> BasicEncoder<B> {
    pub fn forward(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let mut x = instance_norm_act(self.conv1.forward(x), self.norm_eps, true);
        for block in self.layer1.iter().chain(&self.layer2).chain(&self.layer3) {
            x = block.forward(x);
        }
        self.conv2.forward(x)
    }

    /// Both images in one batch, as the reference does; returns (fmap1, fmap2).
    pub fn forward_pair(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
    ) -> (Tensor<B, 4>, Tensor<B, 4>) {
        let n = left.dims()[0];
        let out = self.forward(crate::ops::channels::cat(vec![left, right], 0));
        let [_, c, h, w] = out.dims();
        (
            out.clone().slice([0..n, 0..c, 0..h, 0..w]),
            out.slice([n..2 * n, 0..c, 0..h, 0..w]),
        )
    }
}

impl<B: Backend> ResidualBlock<B> {
    /// [`Self::forward`] as ONNX nodes.
    pub fn emit(&self, g: &mut Graph, x: &Value) -> Value {
        let eps = self.norm_eps;
        let y = self.conv1.emit(g, x);
        let y = g.instance_norm(&y, eps);
        let y = g.relu(&y);
        let y = self.conv2.emit(g, &y);
        let y = g.instance_norm(&y, eps);
        let y = g.relu(&y);
        let shortcut = self.downsample.emit(g, x);
        let shortcut = g.instance_norm(&shortcut, eps);
        let sum = g.add(&shortcut, &y);
        g.relu(&sum)
    }
}

impl<B: Backend> BasicEncoder<B> {
    /// [`Self::forward`] as ONNX nodes.
    pub fn emit(&self, g: &mut Graph, x: &Value) -> Value {
        let x = self.conv1.emit(g, x);
        let x = g.instance_norm(&x, self.norm_eps);
        let mut x = g.relu(&x);
        for block in self.layer1.iter().chain(&self.layer2).chain(&self.layer3) {
            x = block.emit(g, &x);
        }
        self.conv2.emit(g, &x)
    }

    /// [`Self::forward_pair`] as ONNX nodes.
    pub fn emit_pair(&self, g: &mut Graph, left: &Value, right: &Value) -> (Value, Value) {
        let n = left.shape[0];
        let both = g.concat(&[left, right], 0);
        let out = self.emit(g, &both);
        (g.narrow(&out, 0, 0, n), g.narrow(&out, 0, n, n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::CpuAutodiffBackend as A;
    use burn::tensor::Distribution;

    /// The biases an instance normalisation subtracts get a rounding-level gradient; the others
    /// a real one — the fact `bias_cancelled_by_instance_norm` states.
    #[test]
    fn normalised_biases_get_no_gradient() {
        let device = Default::default();
        A::seed(&device, 3);
        let encoder = BasicEncoderConfig::new().init::<A>(&device);
        let x = Tensor::<A, 4>::random([1, 3, 32, 48], Distribution::Uniform(-1.0, 1.0), &device);
        let out = encoder.forward(x);
        let probe = Tensor::<A, 4>::random(out.dims(), Distribution::Normal(0.0, 1.0), &device);
        let grads = (out * probe).sum().backward();
        let size = |t: Option<Tensor<crate::CpuBackend, 1>>| -> f32 {
            t.expect("a gradient").abs().max().into_scalar()
        };
        let cancelled = [
            size(encoder.conv1.bias.as_ref().unwrap().grad(&grads)),
            size(encoder.layer1[0].conv1.bias.as_ref().unwrap().grad(&grads)),
            size(encoder.layer1[0].conv2.bias.as_ref().unwrap().grad(&grads)),
            size(
                encoder.layer1[0]
                    .downsample
                    .bias
                    .as_ref()
                    .unwrap()
                    .grad(&grads),
            ),
        ];
        let kept = size(encoder.conv2.bias.as_ref().unwrap().grad(&grads));
        for (i, c) in cancelled.iter().enumerate() {
            assert!(*c < 1e-4 * kept, "bias {i}: gradient {c} vs {kept}");
        }
        for name in [
            "fnet.conv1.bias",
            "fnet.layer1.0.conv1.bias",
            "fnet.layer3.1.conv2.bias",
            "fnet.layer2.0.downsample.0.bias",
        ] {
            assert!(bias_cancelled_by_instance_norm(name), "{name}");
        }
        for name in [
            "fnet.conv2.bias",
            "fnet.conv1.weight",
            "update_block.gru.convz1.bias",
        ] {
            assert!(!bias_cancelled_by_instance_norm(name), "{name}");
        }
    }

    /// The encoder's nodes (Burn's convolution, the instance norm as graph ops) against
    /// `forward_pair` on Flex (its convolution and instance-norm kernels), both images in one
    /// batch and split again.
    #[test]
    fn emitted_encoder_matches_forward() {
        use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
        use crate::test_util::uniform;
        let encoder = BasicEncoderConfig::new().init::<crate::CpuBackend>(&Default::default());
        let (left, right) = (
            uniform([1, 3, 32, 48], -1.0, 1.0),
            uniform([1, 3, 32, 48], -1.0, 1.0),
        );
        let out = run_emitted(&[left.to_data(), right.to_data()], |g, x| {
            let (a, b) = encoder.emit_pair(g, &x[0], &x[1]);
            vec![a, b]
        });
        let (a, b) = encoder.forward_pair(left, right);
        assert_emit_matches("fmap1", &out[0], a.into_data(), 1e-4);
        assert_emit_matches("fmap2", &out[1], b.into_data(), 1e-4);
    }
}
