//! The GRU gates composed from Burn tensor ops: the fallback where no kernel exists, and the
//! reference the kernels are tested against.

use burn::prelude::*;
use burn::tensor::activation::{sigmoid, tanh};

use crate::ops::conv2d::Conv2d;

/// The gates from the stacked logits `zr` (z then r): `(1 − z)·h + z·tanh(cq([r·h, x]))`.
pub fn gates<B: Backend>(
    zr: Tensor<B, 4>,
    h: Tensor<B, 4>,
    x: Tensor<B, 4>,
    cq: &Conv2d<B>,
) -> Tensor<B, 4> {
    let hidden = h.dims()[1];
    let zr = sigmoid(zr);
    let z = zr.clone().narrow(1, 0, hidden);
    let r = zr.narrow(1, hidden, hidden);
    let q = tanh(cq.forward(crate::ops::channels::cat(vec![r * h.clone(), x], 1)));
    // (1 - z) * h + z * q
    (z.clone().neg().add_scalar(1.0)) * h + z * q
}
