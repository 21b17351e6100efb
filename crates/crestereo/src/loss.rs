//! The reference sequence loss.

use burn::prelude::*;

/// Weighted L1 over all predictions: `Σ_i γ^(n−i−1) · mean(valid · |pred_i − [disp, 0]|)`.
///
/// `preds`: (N, 2, H, W) each; `disp`, `valid`: (N, H, W). The mean runs over all N·2·H·W
/// elements, as in the reference. The paper uses γ = 0.9, the released code 0.8.
pub fn sequence_loss<B: Backend>(
    preds: &[Tensor<B, 4>],
    disp: Tensor<B, 3>,
    valid: Tensor<B, 3>,
    gamma: f64,
) -> Tensor<B, 1> {
    let [n, h, w] = disp.dims();
    let gt = crate::ops::channels::cat(
        vec![
            disp.clone().reshape([n, 1, h, w]),
            Tensor::zeros([n, 1, h, w], (&disp.device(), disp.dtype())),
        ],
        1,
    );
    let valid = valid.reshape([n, 1, h, w]);
    let count = preds.len();
    let mut total: Option<Tensor<B, 1>> = None;
    for (i, pred) in preds.iter().enumerate() {
        let weight = gamma.powi((count - i - 1) as i32);
        let l = (valid.clone() * (pred.clone() - gt.clone()).abs())
            .mean()
            .mul_scalar(weight);
        total = Some(match total {
            Some(t) => t + l,
            None => l,
        });
    }
    total.unwrap_or_else(|| Tensor::zeros([1], (&disp.device(), disp.dtype())))
}
