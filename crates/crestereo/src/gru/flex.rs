//! The GRU gates' element-wise work on the Flex CPU backend, one parallel pass each, with the
//! same formulas as the composed path (and as Flex's own `sigmoid` and `tanh`).
//!
//! Composed, a gate step is a sigmoid, two narrows (strided views), a product, a concatenation,
//! a tanh and four more element-wise ops: each a full pass over the maps on one thread, the
//! products on the narrowed views through Flex's strided iterator.

use burn::backend::flex::FlexTensor;
use burn::tensor::{TensorData, TensorMetadata};
use rayon::prelude::*;

fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// The candidate convolution's input `[σ(r) · h, x]` (N, hidden + C_x, H, W), from the stacked
/// gate logits `zr` (N, 2·hidden, H, W: z then r), the hidden state `h` and the input `x`.
pub(super) fn reset_input(zr: &FlexTensor, h: &FlexTensor, x: &FlexTensor) -> FlexTensor {
    let [n, hidden, height, width] = h.shape().dims();
    let cx = x.shape().dims::<4>()[1];
    let plane = height * width;
    let (zr, h, x) = (zr.to_contiguous(), h.to_contiguous(), x.to_contiguous());
    let (zr, h, x): (&[f32], &[f32], &[f32]) = (zr.storage(), h.storage(), x.storage());
    let c = hidden + cx;
    let mut out = vec![0f32; n * c * plane];
    out.par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
        let (b, ch) = (i / c, i % c);
        if ch < hidden {
            let r = &zr[((b * 2 * hidden) + hidden + ch) * plane..][..plane];
            let h = &h[(b * hidden + ch) * plane..][..plane];
            for ((d, &r), &h) in dst.iter_mut().zip(r).zip(h) {
                *d = sigmoid(r) * h;
            }
        } else {
            dst.copy_from_slice(&x[(b * cx + ch - hidden) * plane..][..plane]);
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, c, height, width]))
}

/// The new hidden state `(1 − σ(z)) · h + σ(z) · tanh(q)` (N, hidden, H, W), from the stacked
/// gate logits `zr`, the hidden state `h` and the candidate logits `q`.
pub(super) fn blend(zr: &FlexTensor, h: &FlexTensor, q: &FlexTensor) -> FlexTensor {
    let [n, hidden, height, width] = h.shape().dims();
    let plane = height * width;
    let (zr, h, q) = (zr.to_contiguous(), h.to_contiguous(), q.to_contiguous());
    let (zr, h, q): (&[f32], &[f32], &[f32]) = (zr.storage(), h.storage(), q.storage());
    let mut out = vec![0f32; n * hidden * plane];
    out.par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
        let (b, ch) = (i / hidden, i % hidden);
        let z = &zr[(b * 2 * hidden + ch) * plane..][..plane];
        let h = &h[i * plane..][..plane];
        let q = &q[i * plane..][..plane];
        for (((d, &z), &h), &q) in dst.iter_mut().zip(z).zip(h).zip(q) {
            let z = sigmoid(z);
            *d = (1.0 - z) * h + z * q.tanh();
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, hidden, height, width]))
}
