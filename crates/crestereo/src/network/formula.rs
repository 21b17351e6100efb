//! The element-wise formulas that `forward` computes on tensors and `emit` writes as graph
//! nodes, each written once as a list of steps both sides apply in the same order (so the
//! reference's order of operations, and with it the float32 bits, is kept on both).

use burn::prelude::*;
use burn::tensor::activation::sigmoid;

use crate::export::onnx::{Graph, Value};

/// One element-wise step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Step {
    DivScalar(f64),
    MulScalar(f64),
    SubScalar(f64),
    Sigmoid,
}

/// BGR values in 0..255 to −1..1, as the reference does inside its forward: `x / 255 · 2 − 1`.
pub(crate) const INPUT_NORMALISATION: [Step; 3] = [
    Step::DivScalar(255.0),
    Step::MulScalar(2.0),
    Step::SubScalar(1.0),
];

/// A level's learned offsets from the logits of its offset convolution:
/// `(sigmoid(x) − 0.5) · 2 · range`, in (−range, range).
pub(crate) fn learned_offsets(range: f64) -> [Step; 3] {
    [
        Step::Sigmoid,
        Step::SubScalar(0.5),
        Step::MulScalar(2.0 * range),
    ]
}

/// `steps` applied to a tensor.
pub(crate) fn apply<B: Backend, const D: usize>(
    mut x: Tensor<B, D>,
    steps: &[Step],
) -> Tensor<B, D> {
    for step in steps {
        x = match *step {
            Step::DivScalar(v) => x.div_scalar(v),
            Step::MulScalar(v) => x.mul_scalar(v),
            Step::SubScalar(v) => x.sub_scalar(v),
            Step::Sigmoid => sigmoid(x),
        };
    }
    x
}

/// `steps` as graph nodes (scalars as float32 constants, the precision `apply` computes in).
pub(crate) fn emit(g: &mut Graph, x: &Value, steps: &[Step]) -> Value {
    let mut x = x.clone();
    for step in steps {
        x = match *step {
            Step::DivScalar(v) => g.div_scalar(&x, v as f32),
            Step::MulScalar(v) => g.mul_scalar(&x, v as f32),
            Step::SubScalar(v) => g.sub_scalar(&x, v as f32),
            Step::Sigmoid => g.sigmoid(&x),
        };
    }
    x
}
