//! Fused adaptive-group-correlation ops: one device-side operation each, with its own backward.
//!
//! * [`offset_corr`]: group correlation of `left` with `right` bilinearly sampled (zeros outside,
//!   align-corners pixel coordinates) at `x + flow + window offset + learned offset`, for every
//!   candidate of a 1×9 or 3×3 search window (the 1/16 and 1/8 levels).
//! * [`warp`]: `right` bilinearly sampled at `x + flow` (the 1/4 level's warp).
//! * [`shift_corr`]: the 1/4 level's group correlation with the warped map at integer window
//!   offsets, replicate border (a Flex kernel; composed elsewhere).
//!
//! None reads anything back to the host. The kernels are implemented per backend through the
//! [`AgclOps`] extension trait: Flex (CPU kernels in `kernels`), CubeCL (`#[cube]` kernels
//! for every CubeCL runtime: CUDA and wgpu, `cuda` / `wgpu` features, plus the `Fusion<B>`
//! wrapper) and `Autodiff<B>` (custom backward calling the inner backend's gradient kernels).
//! The model stays generic over `B: Backend`; [`crate::ops::dispatch`] picks the kernel from the
//! concrete backend type at run time, and every other backend or dtype runs the composed
//! version in [`composed`] (Burn tensor ops, differentiated by autodiff).

mod autodiff;
pub mod composed;
#[cfg(feature = "cube")]
mod cube;
pub mod emit;
mod flex;
pub mod kernels;
mod layout;
mod shift;
mod window;

pub use shift::shift_corr;
pub use window::SearchWindow;

use burn::prelude::*;
use burn::tensor::TensorPrimitive;
use burn::tensor::ops::FloatTensor;

use crate::ops::dispatch::{erase, kernels_f32, on_kernel_backend, unerase};

/// Static parameters of an offset correlation: channel groups and the search window's
/// half-extent (candidates ordered row-major, dy outer, dx inner).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CorrSpec {
    pub groups: usize,
    /// Horizontal half-extent (4 for the 1×9 row, 1 for the 3×3 square).
    pub rx: usize,
    /// Vertical half-extent (0 for the row, 1 for the square).
    pub ry: usize,
}

impl CorrSpec {
    pub fn new(window: SearchWindow, groups: usize) -> Self {
        let (ry, rx) = window.radius();
        Self { groups, rx, ry }
    }

    /// Number of search candidates K.
    pub fn candidates(&self) -> usize {
        (2 * self.rx + 1) * (2 * self.ry + 1)
    }

    /// Integer window offset (dx, dy) of candidate `k`.
    #[inline]
    pub fn window_offset(&self, k: usize) -> (i64, i64) {
        let row = 2 * self.rx + 1;
        (
            (k % row) as i64 - self.rx as i64,
            (k / row) as i64 - self.ry as i64,
        )
    }
}

/// Backend extension: the fused AGCL kernels and their gradients.
///
/// Shapes: `left`, `right` (N, C, H, W); `flow` (N, 2, H, W); `offset` (N, 2K, H, W), channel
/// `2k` = x and `2k+1` = y offset of candidate `k`; correlation output (N, G·K, H, W), channel
/// `g·K + k`.
pub trait AgclOps: Backend {
    fn agcl_offset_corr(
        left: FloatTensor<Self>,
        right: FloatTensor<Self>,
        flow: FloatTensor<Self>,
        offset: FloatTensor<Self>,
        spec: CorrSpec,
    ) -> FloatTensor<Self>;

    /// Gradients w.r.t. (left, right, flow, offset); `None` where `need` is false.
    fn agcl_offset_corr_backward(
        left: FloatTensor<Self>,
        right: FloatTensor<Self>,
        flow: FloatTensor<Self>,
        offset: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: CorrSpec,
        need: [bool; 4],
    ) -> [Option<FloatTensor<Self>>; 4];

    /// `right` (N, C, H, W) sampled at `x + flow` → (N, C, H, W).
    fn agcl_warp(right: FloatTensor<Self>, flow: FloatTensor<Self>) -> FloatTensor<Self>;

    /// Gradients w.r.t. (right, flow); `None` where `need` is false.
    fn agcl_warp_backward(
        right: FloatTensor<Self>,
        flow: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        need: [bool; 2],
    ) -> [Option<FloatTensor<Self>>; 2];
}

fn prim<B: Backend, const D: usize>(t: Tensor<B, D>) -> FloatTensor<B> {
    t.into_primitive().tensor()
}

fn tensor<B: Backend, const D: usize>(p: FloatTensor<B>) -> Tensor<B, D> {
    Tensor::from_primitive(TensorPrimitive::Float(p))
}

/// Fused offset correlation (see [`AgclOps`] for the shapes). Differentiable w.r.t. all four
/// inputs on autodiff backends.
pub fn offset_corr<B: Backend>(
    left: Tensor<B, 4>,
    right: Tensor<B, 4>,
    flow: Tensor<B, 4>,
    offset: Tensor<B, 4>,
    spec: CorrSpec,
) -> Tensor<B, 4> {
    let [n, c, h, w] = left.dims();
    assert_eq!(right.dims(), [n, c, h, w], "AGCL: left/right shapes differ");
    assert_eq!(flow.dims(), [n, 2, h, w], "AGCL: flow shape");
    assert_eq!(
        offset.dims(),
        [n, 2 * spec.candidates(), h, w],
        "AGCL: offset shape"
    );
    assert!(
        spec.groups > 0 && c.is_multiple_of(spec.groups),
        "AGCL: channels not divisible by groups"
    );
    let choice = kernels_f32(&[&left, &right, &flow, &offset]);
    on_kernel_backend!(choice, |I| tensor(unerase(I::agcl_offset_corr(
        erase(prim(left)),
        erase(prim(right)),
        erase(prim(flow)),
        erase(prim(offset)),
        spec
    ))), composed => composed::offset_corr(left, right, flow, offset, spec))
}

/// Fused bilinear warp of `right` (N, C, H, W) by `flow` (N, 2, H, W), zeros outside.
pub fn warp<B: Backend>(right: Tensor<B, 4>, flow: Tensor<B, 4>) -> Tensor<B, 4> {
    let [n, _, h, w] = right.dims();
    assert_eq!(flow.dims(), [n, 2, h, w], "AGCL warp: flow shape");
    let choice = kernels_f32(&[&right, &flow]);
    on_kernel_backend!(choice, |I| tensor(unerase(I::agcl_warp(erase(prim(right)), erase(prim(flow))))),
        composed => composed::warp(right, flow))
}

/// Gradients of [`offset_corr`] through the backend's kernel directly (for tests); `None` on a
/// backend without AGCL kernels.
#[allow(clippy::type_complexity)]
pub fn offset_corr_backward<B: Backend>(
    left: Tensor<B, 4>,
    right: Tensor<B, 4>,
    flow: Tensor<B, 4>,
    offset: Tensor<B, 4>,
    grad: Tensor<B, 4>,
    spec: CorrSpec,
) -> Option<[Tensor<B, 4>; 4]> {
    let choice = kernels_f32(&[&left, &right, &flow, &offset, &grad]);
    let (l, r, f, o, g) = (
        prim(left),
        prim(right),
        prim(flow),
        prim(offset),
        prim(grad),
    );
    let grads: [Option<FloatTensor<B>>; 4] = on_kernel_backend!(choice, |I| unerase(
        I::agcl_offset_corr_backward(erase(l), erase(r), erase(f), erase(o), erase(g), spec, [true; 4])
    ), composed => return None);
    Some(grads.map(|g| tensor(g.expect("all gradients requested"))))
}
