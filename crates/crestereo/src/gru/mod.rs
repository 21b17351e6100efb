//! Separable ConvGRU: a 1×5 (horizontal) GRU step followed by a 5×1 (vertical) one.
//!
//! On the plain Flex backend (inference) the gates' element-wise work runs as two parallel
//! kernels (`flex`); elsewhere it is composed from tensor ops.

use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::activation::{sigmoid, tanh};

use crate::dispatch::{flex_f32, from_flex};
use crate::encoder::conv_cfg;

mod flex;

#[derive(Config, Debug)]
pub struct SepConvGruConfig {
    #[config(default = 128)]
    pub hidden_dim: usize,
    /// Context (128) + motion features (128).
    #[config(default = 256)]
    pub input_dim: usize,
}

#[derive(Module, Debug)]
pub struct SepConvGru<B: Backend> {
    pub convz1: Conv2d<B>,
    pub convr1: Conv2d<B>,
    pub convq1: Conv2d<B>,
    pub convz2: Conv2d<B>,
    pub convr2: Conv2d<B>,
    pub convq2: Conv2d<B>,
}

impl SepConvGruConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> SepConvGru<B> {
        let cin = self.hidden_dim + self.input_dim;
        let h = self.hidden_dim;
        let horiz = || conv_cfg(cin, h, [1, 5], 1, [0, 2]).init(device);
        let vert = || conv_cfg(cin, h, [5, 1], 1, [2, 0]).init(device);
        SepConvGru {
            convz1: horiz(),
            convr1: horiz(),
            convq1: horiz(),
            convz2: vert(),
            convr2: vert(),
            convq2: vert(),
        }
    }
}

fn gru_step<B: Backend>(
    h: Tensor<B, 4>,
    x: Tensor<B, 4>,
    cz: &Conv2d<B>,
    cr: &Conv2d<B>,
    cq: &Conv2d<B>,
) -> Tensor<B, 4> {
    let hx = Tensor::cat(vec![h.clone(), x.clone()], 1);
    // z and r read the same input: one stacked convolution, then split.
    let zr = crate::conv2d::forward_stacked(&[cz, cr], hx);
    if let Some([zr_f, h_f, x_f]) = flex_f32([&zr, &h, &x]) {
        let q = crate::conv2d::forward(cq, from_flex(flex::reset_input(&zr_f, &h_f, &x_f)));
        let [q_f] = flex_f32([&q]).expect("a Flex tensor");
        return from_flex(flex::blend(&zr_f, &h_f, &q_f));
    }
    let hidden = h.dims()[1];
    let zr = sigmoid(zr);
    let z = zr.clone().narrow(1, 0, hidden);
    let r = zr.narrow(1, hidden, hidden);
    let q = tanh(crate::conv2d::forward(
        cq,
        Tensor::cat(vec![r * h.clone(), x], 1),
    ));
    // (1 - z) * h + z * q
    (z.clone().neg().add_scalar(1.0)) * h + z * q
}

impl<B: Backend> SepConvGru<B> {
    pub fn forward(&self, h: Tensor<B, 4>, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let h = gru_step(h, x.clone(), &self.convz1, &self.convr1, &self.convq1);
        gru_step(h, x, &self.convz2, &self.convr2, &self.convq2)
    }
}

#[cfg(test)]
mod tests {
    use burn::module::AutodiffModule;
    use burn::tensor::Distribution;

    use super::*;
    use crate::{CpuAutodiffBackend, CpuBackend};

    /// The GRU with its Flex gate kernels (plain Flex) against the composed gates (taken under
    /// autodiff), same weights and inputs.
    #[test]
    fn flex_gates_match_the_composed_ops() {
        let device = Default::default();
        let gru = SepConvGruConfig::new()
            .with_hidden_dim(16)
            .with_input_dim(24)
            .init::<CpuAutodiffBackend>(&device);
        let h = Tensor::<CpuBackend, 4>::random(
            [2, 16, 9, 11],
            Distribution::Normal(0.0, 1.0),
            &device,
        )
        .tanh();
        let x = Tensor::<CpuBackend, 4>::random(
            [2, 24, 9, 11],
            Distribution::Normal(0.0, 1.0),
            &device,
        );
        let composed = gru
            .forward(Tensor::from_inner(h.clone()), Tensor::from_inner(x.clone()))
            .inner();
        let kernel = gru.valid().forward(h, x);
        let diff: f32 = (kernel - composed).abs().max().into_scalar();
        assert!(diff < 1e-5, "max difference {diff}");
    }
}
