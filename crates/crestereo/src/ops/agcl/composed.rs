//! The AGCL ops composed from Burn tensor ops: the fallback on backends (and dtypes) without
//! kernels, and the reference the kernels are tested against. Everything stays on the device:
//! sampling coordinates, corner indices and the inside-the-image masks are tensors, the
//! corners are gathered, and autodiff differentiates the composition (through the bilinear
//! weights for the coordinates, through the gather for the sampled map).

use burn::prelude::*;

use super::CorrSpec;

/// `img` (N, C, H, W) bilinearly sampled at pixel coordinates `x`, `y` (N, P), zero outside
/// the image (align-corners convention: pixel centres at integers) → (N, C, P).
pub fn sample_bilinear_zeros<B: Backend>(
    img: Tensor<B, 4>,
    x: Tensor<B, 2>,
    y: Tensor<B, 2>,
) -> Tensor<B, 3> {
    let [n, c, h, w] = img.dims();
    let [_, p] = x.dims();
    let table = img.reshape([n, c, h * w]);
    let x0 = x.clone().floor();
    let y0 = y.clone().floor();
    let wx1 = x - x0.clone();
    let wy1 = y - y0.clone();
    let wx0 = wx1.clone().neg().add_scalar(1.0);
    let wy0 = wy1.clone().neg().add_scalar(1.0);
    let corners = [
        (x0.clone(), y0.clone(), wx0.clone() * wy0.clone()),
        (x0.clone().add_scalar(1.0), y0.clone(), wx1.clone() * wy0),
        (x0.clone(), y0.clone().add_scalar(1.0), wx0 * wy1.clone()),
        (x0.add_scalar(1.0), y0.add_scalar(1.0), wx1 * wy1),
    ];
    let (wmax, hmax) = ((w - 1) as f64, (h - 1) as f64);
    corners
        .into_iter()
        .map(|(cx, cy, weight)| {
            let inside = cx
                .clone()
                .greater_equal_elem(0.0)
                .bool_and(cx.clone().lower_equal_elem(wmax))
                .bool_and(cy.clone().greater_equal_elem(0.0))
                .bool_and(cy.clone().lower_equal_elem(hmax));
            let index = (cy.clamp(0.0, hmax).mul_scalar(w as f64) + cx.clamp(0.0, wmax))
                .int()
                .reshape([n, 1, p])
                .expand([n, c, p]);
            let weight = weight.mask_fill(inside.bool_not(), 0.0).reshape([n, 1, p]);
            table.clone().gather(2, index) * weight
        })
        .reduce(|a, b| a + b)
        .expect("four corners")
}

/// Column and row coordinates of every pixel, (1, 1, H, W) each, on `like`'s device in its
/// float dtype.
fn pixel_grid<B: Backend>(h: usize, w: usize, like: &Tensor<B, 4>) -> (Tensor<B, 4>, Tensor<B, 4>) {
    let (device, dtype) = (&like.device(), like.dtype());
    let xs = Tensor::<B, 1, Int>::arange(0..w as i64, device)
        .float()
        .reshape([1, 1, 1, w])
        .expand([1, 1, h, w]);
    let ys = Tensor::<B, 1, Int>::arange(0..h as i64, device)
        .float()
        .reshape([1, 1, h, 1])
        .expand([1, 1, h, w]);
    (
        crate::ops::float_like(xs, dtype),
        crate::ops::float_like(ys, dtype),
    )
}

/// Window offsets (dx, dy) of the candidates as (1, K, 1, 1) tensors, on `like`'s device in
/// its float dtype.
fn window_offsets<B: Backend>(spec: CorrSpec, like: &Tensor<B, 4>) -> (Tensor<B, 4>, Tensor<B, 4>) {
    let device = &like.device();
    let k = spec.candidates();
    let (dx, dy): (Vec<f32>, Vec<f32>) = (0..k)
        .map(|i| {
            let (dx, dy) = spec.window_offset(i);
            (dx as f32, dy as f32)
        })
        .unzip();
    let t = |v: Vec<f32>| {
        let t = Tensor::<B, 1>::from_floats(v.as_slice(), device).reshape([1, k, 1, 1]);
        crate::ops::float_like(t, like.dtype())
    };
    (t(dx), t(dy))
}

/// Offset correlation (shapes as in [`super::AgclOps`]).
pub fn offset_corr<B: Backend>(
    left: Tensor<B, 4>,
    right: Tensor<B, 4>,
    flow: Tensor<B, 4>,
    offset: Tensor<B, 4>,
    spec: CorrSpec,
) -> Tensor<B, 4> {
    let [n, c, h, w] = left.dims();
    let (k, g) = (spec.candidates(), spec.groups);
    let (gx, gy) = pixel_grid(h, w, &left);
    let (dx, dy) = window_offsets(spec, &left);
    let offset = offset.reshape([n, k, 2, h, w]);
    let ox = offset.clone().narrow(2, 0, 1).reshape([n, k, h, w]);
    let oy = offset.narrow(2, 1, 1).reshape([n, k, h, w]);
    let fx = flow.clone().narrow(1, 0, 1);
    let fy = flow.narrow(1, 1, 1);
    let x = (gx + fx + dx + ox).reshape([n, k * h * w]);
    let y = (gy + fy + dy + oy).reshape([n, k * h * w]);
    let sampled = sample_bilinear_zeros(right, x, y).reshape([n, g, c / g, k, h * w]);
    let left = left.reshape([n, g, c / g, 1, h * w]);
    (left * sampled).mean_dim(2).reshape([n, g * k, h, w])
}

/// `right` sampled at `x + flow`, zeros outside.
pub fn warp<B: Backend>(right: Tensor<B, 4>, flow: Tensor<B, 4>) -> Tensor<B, 4> {
    let [n, c, h, w] = right.dims();
    let (gx, gy) = pixel_grid(h, w, &right);
    let x = (gx + flow.clone().narrow(1, 0, 1)).reshape([n, h * w]);
    let y = (gy + flow.narrow(1, 1, 1)).reshape([n, h * w]);
    sample_bilinear_zeros(right, x, y).reshape([n, c, h, w])
}

/// `x` (N, C, H, W) with its border columns repeated `rx` times on each side and its border
/// rows `ry` times (replicate padding made of slices, in `x`'s dtype: Burn's edge `pad` fails
/// on float64 Flex tensors).
fn pad_edge<B: Backend>(x: Tensor<B, 4>, rx: usize, ry: usize) -> Tensor<B, 4> {
    let pad = |x: Tensor<B, 4>, dim: usize, r: usize| {
        if r == 0 {
            return x;
        }
        let last = x.dims()[dim] - 1;
        let first = x.clone().narrow(dim, 0, 1).repeat_dim(dim, r);
        let end = x.clone().narrow(dim, last, 1).repeat_dim(dim, r);
        crate::ops::channels::cat(vec![first, x, end], dim)
    };
    pad(pad(x, 3, rx), 2, ry)
}

/// The 1/4 level's shifted correlation: edge pad, one crop per candidate, products and group
/// means.
pub fn shift_corr<B: Backend>(
    left: Tensor<B, 4>,
    warped: Tensor<B, 4>,
    spec: CorrSpec,
) -> Tensor<B, 4> {
    let [n, c, h, w] = left.dims();
    let (rx, ry, g) = (spec.rx, spec.ry, spec.groups);
    let padded = pad_edge(warped, rx, ry);
    let corrs: Vec<Tensor<B, 5>> = (0..spec.candidates())
        .map(|k| {
            let (dx, dy) = spec.window_offset(k);
            let oy = (dy + ry as i64) as usize;
            let ox = (dx + rx as i64) as usize;
            let crop = padded.clone().slice([0..n, 0..c, oy..oy + h, ox..ox + w]);
            (left.clone() * crop)
                .reshape([n, g, c / g, h, w])
                .mean_dim(2)
        })
        .collect();
    crate::ops::channels::cat(corrs, 2).reshape([n, g * spec.candidates(), h, w])
}
