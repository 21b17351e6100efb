//! The GRU gates' element-wise work on the Flex CPU backend, one parallel pass each, with the
//! same formulas as the composed path (and as Flex's own `sigmoid` and `tanh`).
//!
//! Composed, a gate step is a sigmoid, two narrows (strided views), a product, a concatenation,
//! a tanh and four more element-wise ops: each a full pass over the maps on one thread, the
//! products on the narrowed views through Flex's strided iterator.

use burn::backend::flex::FlexTensor;
use burn::tensor::{TensorData, TensorMetadata};
use rayon::prelude::*;

use crate::ops::simd;

/// How the gates evaluate σ and tanh.
///
/// `Std`: the standard library's `exp`/`tanh`, as Flex's own ops do; training takes it, since
/// every rounding difference in the forward reaches the gradients that the parity tests check
/// against the float64 reference. `Vectorised`: [`crate::ops::simd`]'s polynomial exp (a few float32
/// ulps from std, absolute error ≤ 3e-7 on σ and tanh) in loops compiled for AVX2, several
/// times faster; inference takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum GateMath {
    Std,
    Vectorised,
}

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
pub(super) fn reset_input(
    zr: &FlexTensor,
    h: &FlexTensor,
    x: &FlexTensor,
    math: GateMath,
) -> FlexTensor {
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
            match math {
                GateMath::Std => {
                    for ((d, &r), &h) in dst.iter_mut().zip(r).zip(h) {
                        *d = sigmoid(r) * h;
                    }
                }
                GateMath::Vectorised => {
                    simd::map3(dst, r, h, h, |r, h, _| simd::sigmoid(r) * h);
                }
            }
        } else {
            dst.copy_from_slice(&x[(b * cx + ch - hidden) * plane..][..plane]);
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, c, height, width]))
}

/// The new hidden state `(1 − σ(z)) · h + σ(z) · tanh(q)` (N, hidden, H, W), from the stacked
/// gate logits `zr`, the hidden state `h` and the candidate logits `q`.
pub(super) fn blend(zr: &FlexTensor, h: &FlexTensor, q: &FlexTensor, math: GateMath) -> FlexTensor {
    blend_with(zr, h, q, Some(math))
}

/// [`blend`] from the candidate `t = tanh(q)` itself (training keeps `t` for the backward).
pub(super) fn blend_tanh(zr: &FlexTensor, h: &FlexTensor, t: &FlexTensor) -> FlexTensor {
    blend_with(zr, h, t, None)
}

/// `tanh(q)` element-wise, in parallel.
pub(super) fn tanh(q: &FlexTensor) -> FlexTensor {
    let shape = q.shape();
    let q = q.to_contiguous();
    let q: &[f32] = q.storage();
    let mut out = vec![0f32; q.len()];
    out.par_chunks_mut(1 << 14)
        .zip(q.par_chunks(1 << 14))
        .for_each(|(o, q)| o.iter_mut().zip(q).for_each(|(o, q)| *o = q.tanh()));
    FlexTensor::from_data(TensorData::new(out, shape))
}

/// [`blend`] (`tanh` applied to `q` with this math) or [`blend_tanh`] (`tanh: None`, `q` is
/// the candidate already).
fn blend_with(
    zr: &FlexTensor,
    h: &FlexTensor,
    q: &FlexTensor,
    tanh: Option<GateMath>,
) -> FlexTensor {
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
        let mut std = |candidate: fn(f32) -> f32| {
            for (((d, &z), &h), &q) in dst.iter_mut().zip(z).zip(h).zip(q) {
                let z = sigmoid(z);
                *d = (1.0 - z) * h + z * candidate(q);
            }
        };
        match tanh {
            None => std(|t| t),
            Some(GateMath::Std) => std(f32::tanh),
            Some(GateMath::Vectorised) => simd::map3(dst, z, h, q, |z, h, q| {
                let z = simd::sigmoid(z);
                (1.0 - z) * h + z * simd::tanh(q)
            }),
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, hidden, height, width]))
}

/// A zero-filled (N, 2·hidden, H, W) gradient of the stacked logits with one half written:
/// `fill(b, ch, dst)` writes plane `ch` (< hidden) of image `b` into the half at `offset`.
fn half_of_stacked(
    [n, hidden, height, width]: [usize; 4],
    offset: usize,
    fill: impl Fn(usize, usize, &mut [f32]) + Sync,
) -> FlexTensor {
    let plane = height * width;
    let mut out = vec![0f32; n * 2 * hidden * plane];
    out.par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
        let (b, ch) = (i / (2 * hidden), i % (2 * hidden));
        if (offset..offset + hidden).contains(&ch) {
            fill(b, ch - offset, dst);
        }
    });
    FlexTensor::from_data(TensorData::new(out, [n, 2 * hidden, height, width]))
}

/// Gradients of [`reset_input`] from the gradient `d` of its output: (d zr, d h, d x).
pub(super) fn reset_input_grad(
    zr: &FlexTensor,
    h: &FlexTensor,
    d: &FlexTensor,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let dims @ [n, hidden, height, width] = h.shape().dims();
    let c = d.shape().dims::<4>()[1];
    let (cx, plane) = (c - hidden, height * width);
    let (zr, h, d) = (zr.to_contiguous(), h.to_contiguous(), d.to_contiguous());
    let (zr, h, d): (&[f32], &[f32], &[f32]) = (zr.storage(), h.storage(), d.storage());
    let r = |b: usize, ch: usize| &zr[(b * 2 * hidden + hidden + ch) * plane..][..plane];
    let dr = |b: usize, ch: usize| &d[(b * c + ch) * plane..][..plane];
    // d zr (r half) = d · h · σ'(r).
    let dzr = half_of_stacked(dims, hidden, |b, ch, dst| {
        let hp = &h[(b * hidden + ch) * plane..][..plane];
        for (((o, &r), &h), &g) in dst.iter_mut().zip(r(b, ch)).zip(hp).zip(dr(b, ch)) {
            let s = sigmoid(r);
            *o = g * h * (s * (1.0 - s));
        }
    });
    // d h = d · σ(r).
    let mut dh = vec![0f32; n * hidden * plane];
    dh.par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
        let (b, ch) = (i / hidden, i % hidden);
        for ((o, &r), &g) in dst.iter_mut().zip(r(b, ch)).zip(dr(b, ch)) {
            *o = g * sigmoid(r);
        }
    });
    // d x = the x part of d.
    let mut dx = vec![0f32; n * cx * plane];
    dx.par_chunks_mut(plane).enumerate().for_each(|(i, dst)| {
        let (b, ch) = (i / cx, i % cx);
        dst.copy_from_slice(dr(b, hidden + ch));
    });
    (
        dzr,
        FlexTensor::from_data(TensorData::new(dh, dims)),
        FlexTensor::from_data(TensorData::new(dx, [n, cx, height, width])),
    )
}

/// Gradients of [`blend`] from the gradient `d` of the new hidden state, given the candidate
/// `t = tanh(q)`: (d zr, d h, d q).
pub(super) fn blend_grad(
    zr: &FlexTensor,
    h: &FlexTensor,
    t: &FlexTensor,
    d: &FlexTensor,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let dims @ [n, hidden, height, width] = h.shape().dims();
    let plane = height * width;
    let (zr, h) = (zr.to_contiguous(), h.to_contiguous());
    let (t, d) = (t.to_contiguous(), d.to_contiguous());
    let (zr, h, t, d): (&[f32], &[f32], &[f32], &[f32]) =
        (zr.storage(), h.storage(), t.storage(), d.storage());
    let z = |b: usize, ch: usize| &zr[(b * 2 * hidden + ch) * plane..][..plane];
    let planes = |i: usize| i * plane..(i + 1) * plane;
    // d zr (z half) = d · (t − h) · σ'(z).
    let dzr = half_of_stacked(dims, 0, |b, ch, dst| {
        let i = b * hidden + ch;
        let (hp, tp, dp) = (&h[planes(i)], &t[planes(i)], &d[planes(i)]);
        for ((((o, &z), &h), &t), &g) in dst.iter_mut().zip(z(b, ch)).zip(hp).zip(tp).zip(dp) {
            let s = sigmoid(z);
            *o = g * (t - h) * (s * (1.0 - s));
        }
    });
    // d h = d · (1 − σ(z)); d q = d · σ(z) · (1 − t²).
    let mut dh = vec![0f32; n * hidden * plane];
    let mut dq = vec![0f32; n * hidden * plane];
    dh.par_chunks_mut(plane)
        .zip(dq.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(i, (dh, dq))| {
            let (b, ch) = (i / hidden, i % hidden);
            let (tp, dp) = (&t[planes(i)], &d[planes(i)]);
            for ((((oh, oq), &z), &t), &g) in dh.iter_mut().zip(dq).zip(z(b, ch)).zip(tp).zip(dp) {
                let s = sigmoid(z);
                *oh = g * (1.0 - s);
                *oq = g * s * (1.0 - t * t);
            }
        });
    (
        dzr,
        FlexTensor::from_data(TensorData::new(dh, dims)),
        FlexTensor::from_data(TensorData::new(dq, dims)),
    )
}
