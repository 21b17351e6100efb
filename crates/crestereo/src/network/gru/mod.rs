//! Separable ConvGRU: a 1×5 (horizontal) GRU step followed by a 5×1 (vertical) one.
//!
//! On the Flex backend the gates' element-wise work runs as two parallel kernels (`flex`); under
//! autodiff on Flex (training) as the same kernels recorded with their own backward
//! (`autodiff`); elsewhere it is composed from tensor ops.

use burn::prelude::*;

use crate::network::encoder::conv_cfg;
use crate::ops::conv2d::Conv2d;
use crate::ops::dispatch::{
    Kernels, from_autodiff_flex, from_flex, kernels_f32, to_autodiff_flex, to_flex,
};

mod autodiff;
pub mod composed;
mod flex;

use flex::GateMath;

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
    let hx = crate::ops::channels::cat_channels(h.clone(), x.clone());
    // z and r read the same input: one stacked convolution, then split.
    let zr = crate::ops::conv2d::forward_stacked(&[cz, cr], hx);
    gates(zr, h, x, cq)
}

/// The gates from the stacked logits `zr` (z then r) and the candidate convolution `cq`: by the
/// Flex kernels (with their own backward under autodiff), else [`composed::gates`].
fn gates<B: Backend>(
    zr: Tensor<B, 4>,
    h: Tensor<B, 4>,
    x: Tensor<B, 4>,
    cq: &Conv2d<B>,
) -> Tensor<B, 4> {
    match kernels_f32(&[&zr, &h, &x]) {
        Kernels::Flex => {
            // Plain Flex is inference: the vectorised σ and tanh (see `GateMath`).
            let math = GateMath::Vectorised;
            let (zr, h, x) = (to_flex(zr), to_flex(h), to_flex(x));
            let q = cq.forward(from_flex(flex::reset_input(&zr, &h, &x, math)));
            from_flex(flex::blend(&zr, &h, &to_flex(q), math))
        }
        Kernels::AutodiffFlex => {
            let (zr, h) = (to_autodiff_flex(zr), to_autodiff_flex(h));
            let r_input = autodiff::reset_input(zr.clone(), h.clone(), to_autodiff_flex(x));
            let q = cq.forward(from_autodiff_flex(r_input));
            from_autodiff_flex(autodiff::blend(zr, h, to_autodiff_flex(q)))
        }
        _ => composed::gates(zr, h, x, cq),
    }
}

impl<B: Backend> SepConvGru<B> {
    pub fn forward(&self, h: Tensor<B, 4>, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let h = gru_step(h, x.clone(), &self.convz1, &self.convr1, &self.convq1);
        gru_step(h, x, &self.convz2, &self.convr2, &self.convq2)
    }
}

/// One GRU step as ONNX nodes, in the order of operations of [`composed::gates`].
fn emit_gru_step<B: Backend>(
    g: &mut crate::export::onnx::Graph,
    h: &crate::export::onnx::Value,
    x: &crate::export::onnx::Value,
    [cz, cr, cq]: [&Conv2d<B>; 3],
) -> crate::export::onnx::Value {
    let hx = g.concat(&[h, x], 1);
    let z = cz.emit(g, &hx);
    let z = g.sigmoid(&z);
    let r = cr.emit(g, &hx);
    let r = g.sigmoid(&r);
    let rh = g.mul(&r, h);
    let q = g.concat(&[&rh, x], 1);
    let q = cq.emit(g, &q);
    let q = g.tanh(&q);
    let keep = g.neg(&z);
    let keep = g.add_scalar(&keep, 1.0);
    let kept = g.mul(&keep, h);
    let new = g.mul(&z, &q);
    g.add(&kept, &new)
}

impl<B: Backend> SepConvGru<B> {
    /// [`Self::forward`] as ONNX nodes.
    pub fn emit(
        &self,
        g: &mut crate::export::onnx::Graph,
        h: &crate::export::onnx::Value,
        x: &crate::export::onnx::Value,
    ) -> crate::export::onnx::Value {
        let h = emit_gru_step(g, h, x, [&self.convz1, &self.convr1, &self.convq1]);
        emit_gru_step(g, &h, x, [&self.convz2, &self.convr2, &self.convq2])
    }
}

#[cfg(test)]
mod tests {
    use burn::module::AutodiffModule;
    use burn::tensor::Distribution;

    use super::*;
    use crate::test_util::{assert_output_and_grads_close, max_abs};
    use crate::{CpuAutodiffBackend, CpuBackend};

    fn random<B: Backend>(shape: [usize; 4], device: &B::Device) -> Tensor<B, 4> {
        Tensor::random(shape, Distribution::Normal(0.0, 1.0), device)
    }

    /// A GRU small enough for quick tests: 16 hidden channels, 24 input channels.
    fn small_gru<B: Backend>(device: &B::Device) -> SepConvGru<B> {
        SepConvGruConfig::new()
            .with_hidden_dim(16)
            .with_input_dim(24)
            .init(device)
    }

    /// A hidden state (in tanh's range) and an input for [`small_gru`].
    fn hidden_and_input<B: Backend>(device: &B::Device) -> (Tensor<B, 4>, Tensor<B, 4>) {
        let h = random::<B>([2, 16, 9, 11], device).tanh();
        (h, random::<B>([2, 24, 9, 11], device))
    }

    /// The GRU with its Flex gate kernels (plain Flex) against the composed gates (taken under
    /// autodiff), same weights and inputs.
    #[test]
    fn flex_gates_match_the_composed_ops() {
        let device = Default::default();
        let gru = small_gru::<CpuAutodiffBackend>(&device);
        let (h, x) = hidden_and_input::<CpuBackend>(&device);
        let q = &gru.valid().convq1;
        let zr = random::<CpuBackend>([2, 32, 9, 11], &device).mul_scalar(2.0);
        let kernel = gates(zr.clone(), h.clone(), x.clone(), q);
        let composed = composed::gates(zr, h, x, q);
        let diff = max_abs(kernel, composed);
        assert!(diff < 1e-5, "max difference {diff}");
    }

    /// Under autodiff on Flex: the kernels' output and the gradients their backward gives (the
    /// logits, hidden state, input, and the candidate convolution's weights) against autodiff of
    /// the composed gates.
    #[test]
    fn autodiff_gates_match_the_composed_ops_and_their_gradients() {
        type A = CpuAutodiffBackend;
        let device = Default::default();
        let gru = small_gru::<A>(&device);
        let inputs = (
            random::<CpuBackend>([2, 32, 9, 11], &device).mul_scalar(2.0),
            random::<CpuBackend>([2, 16, 9, 11], &device).tanh(),
            random::<CpuBackend>([2, 24, 9, 11], &device),
        );
        let weights = random::<CpuBackend>([2, 16, 9, 11], &device);
        let run = |kernel: bool| {
            let track =
                |t: &Tensor<CpuBackend, 4>| Tensor::<A, 4>::from_inner(t.clone()).require_grad();
            let (zr, h, x) = (track(&inputs.0), track(&inputs.1), track(&inputs.2));
            let out = if kernel {
                gates(zr.clone(), h.clone(), x.clone(), &gru.convq1)
            } else {
                composed::gates(zr.clone(), h.clone(), x.clone(), &gru.convq1)
            };
            let grads = (out.clone() * Tensor::from_inner(weights.clone()))
                .sum()
                .backward();
            let wq = gru.convq1.weight.val();
            let g = |t: &Tensor<A, 4>| t.grad(&grads).expect("a gradient");
            (out.inner(), [g(&zr), g(&h), g(&x), g(&wq)])
        };
        assert_output_and_grads_close(
            "GRU gates",
            ["zr", "h", "x", "convq weight"],
            run(true),
            run(false),
        );
    }

    /// Both GRU steps as graph nodes (two convolutions where `forward` stacks z and r into one)
    /// against `forward` with the Flex gate kernels.
    #[test]
    fn emitted_gru_matches_forward() {
        use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
        let device = Default::default();
        let gru = small_gru::<CpuBackend>(&device);
        let (h, x) = hidden_and_input::<CpuBackend>(&device);
        let out = run_emitted(&[h.to_data(), x.to_data()], |g, v| {
            vec![gru.emit(g, &v[0], &v[1])]
        });
        assert_emit_matches("GRU", &out[0], gru.forward(h, x).into_data(), 1e-5);
    }
}
