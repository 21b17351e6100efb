//! Adaptive Group Correlation Layer (AGCL).
//!
//! Features are split into `groups` channel groups; for every group and every search candidate
//! the correlation is the mean over the group's channels of `left · right(candidate)`.
//! Candidates alternate between a 1×9 row (dx = −4..4) and a 3×3 square, dilation 1, ordered
//! row-major (dy outer, dx inner). Output channel `g·9 + k` = group `g`, candidate `k`.
//!
//! * 1/16 and 1/8 ([`AdaptiveGroupCorrelation::corr_offset`]): each candidate is bilinearly
//!   sampled at `grid + flow + window offset + learned offset` (zero padding).
//! * 1/4 ([`AdaptiveGroupCorrelation::corr_warp`]): the right map is warped once by the flow,
//!   replicate-padded and shifted by the integer window offsets.

use burn::prelude::*;
use burn::tensor::ops::PadMode;

use crate::attention::{LoFTREncoderLayer, from_tokens, to_tokens};

/// The two search windows alternated over the iterations (even: row, odd: square).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SearchWindow {
    /// 1×9 horizontal window (the reference's `small_patch = False`).
    Row1x9,
    /// 3×3 window (the reference's `small_patch = True`).
    Square3x3,
}

impl SearchWindow {
    /// Window used at iteration `itr` of a level.
    pub fn for_iteration(itr: usize) -> Self {
        if itr.is_multiple_of(2) {
            SearchWindow::Row1x9
        } else {
            SearchWindow::Square3x3
        }
    }

    /// (ry, rx) half-extent.
    pub fn radius(self) -> (usize, usize) {
        match self {
            SearchWindow::Row1x9 => (0, 4),
            SearchWindow::Square3x3 => (1, 1),
        }
    }

    /// Integer offsets (dx, dy), dy outer, dx inner.
    pub fn offsets(self) -> Vec<(i64, i64)> {
        let (ry, rx) = self.radius();
        let (ry, rx) = (ry as i64, rx as i64);
        let mut v = Vec::new();
        for dy in -ry..=ry {
            for dx in -rx..=rx {
                v.push((dx, dy));
            }
        }
        v
    }
}

#[derive(Config, Debug)]
pub struct AdaptiveGroupCorrelationConfig {
    #[config(default = 4)]
    pub groups: usize,
}

/// Correlation state for one pyramid level: the left / right feature maps (N, C, H, W).
#[derive(Clone, Debug)]
pub struct AdaptiveGroupCorrelation<B: Backend> {
    pub fmap1: Tensor<B, 4>,
    pub fmap2: Tensor<B, 4>,
    pub groups: usize,
}

impl AdaptiveGroupCorrelationConfig {
    pub fn init<B: Backend>(
        &self,
        fmap1: Tensor<B, 4>,
        fmap2: Tensor<B, 4>,
    ) -> AdaptiveGroupCorrelation<B> {
        assert_eq!(
            fmap1.dims(),
            fmap2.dims(),
            "AGCL: left/right feature shapes differ"
        );
        assert!(
            fmap1.dims()[1].is_multiple_of(self.groups),
            "AGCL: channels not divisible by groups"
        );
        AdaptiveGroupCorrelation {
            fmap1,
            fmap2,
            groups: self.groups,
        }
    }
}

/// Bilinear sampling of `img` (N, C, H, W) at pixel coordinates `x`, `y` (N, P), zero outside —
/// PyTorch's `grid_sample(align_corners=True, padding_mode="zeros")` on pixel coordinates.
/// Returns (N, P, C). Differentiable w.r.t. `img` and the coordinates.
pub fn bilinear_sample_points<B: Backend>(
    img: Tensor<B, 4>,
    x: Tensor<B, 2>,
    y: Tensor<B, 2>,
) -> Tensor<B, 3> {
    let [n, c, h, w] = img.dims();
    let [_, p] = x.dims();
    let device = img.device();
    // rows: all pixels of all images, plus one zero row for out-of-range corners
    let table = Tensor::cat(
        vec![
            img.permute([0, 2, 3, 1]).reshape([n * h * w, c]),
            Tensor::zeros([1, c], &device),
        ],
        0,
    );
    let np = n * p;
    let corners = Corners::locate(&host_values(&x), &host_values(&y), [n, p], [h, w]);
    let x0 = Tensor::<B, 2>::from_data(TensorData::new(corners.x0, [n, p]), &device);
    let y0 = Tensor::<B, 2>::from_data(TensorData::new(corners.y0, [n, p]), &device);
    let wx1 = x - x0; // fractional parts (carry the coordinate gradient)
    let wy1 = y - y0;
    let wx0 = wx1.clone().neg().add_scalar(1.0);
    let wy0 = wy1.clone().neg().add_scalar(1.0);
    let weights = Tensor::stack::<3>(
        vec![
            wx0.clone() * wy0.clone(),
            wx1.clone() * wy0,
            wx0 * wy1.clone(),
            wx1 * wy1,
        ],
        0,
    ) // 4 n p
    .reshape([4, np, 1]);
    let idx = Tensor::<B, 1, Int>::from_data(TensorData::new(corners.rows, [4 * np]), &device);
    let selected = table.select(0, idx).reshape([4, np, c]);
    (selected * weights).sum_dim(0).reshape([n, p, c])
}

/// A coordinate tensor's values on the host. Only the fractional weights carry the gradient,
/// so the integer corners are computed from detached values.
fn host_values<B: Backend>(t: &Tensor<B, 2>) -> Vec<f32> {
    t.clone()
        .detach()
        .into_data()
        .convert::<f32>()
        .into_vec()
        .expect("coordinates")
}

/// The four corners of every sampling point.
struct Corners {
    /// floor(x), floor(y) per point (N·P).
    x0: Vec<f32>,
    y0: Vec<f32>,
    /// Table rows of the (x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1) corners, corner-major
    /// (4·N·P); a corner outside the image points at the zero row `N·H·W`.
    rows: Vec<i64>,
}

impl Corners {
    fn locate(xs: &[f32], ys: &[f32], [n, p]: [usize; 2], [h, w]: [usize; 2]) -> Self {
        let np = n * p;
        let zero_row = (n * h * w) as i64;
        let mut out = Corners { x0: vec![0f32; np], y0: vec![0f32; np], rows: vec![0i64; 4 * np] };
        for b in 0..n {
            let base = (b * h * w) as i64;
            let row = |xx: f32, yy: f32| -> i64 {
                if xx >= 0.0 && yy >= 0.0 && xx <= (w - 1) as f32 && yy <= (h - 1) as f32 {
                    base + yy as i64 * w as i64 + xx as i64
                } else {
                    zero_row
                }
            };
            for i in b * p..(b + 1) * p {
                let (fx, fy) = (xs[i].floor(), ys[i].floor());
                out.x0[i] = fx;
                out.y0[i] = fy;
                out.rows[i] = row(fx, fy);
                out.rows[np + i] = row(fx + 1.0, fy);
                out.rows[2 * np + i] = row(fx, fy + 1.0);
                out.rows[3 * np + i] = row(fx + 1.0, fy + 1.0);
            }
        }
        out
    }
}

/// Pixel grid (x, y) of size (H, W) as two (1, 1, H, W) tensors.
fn pixel_grid<B: Backend>(h: usize, w: usize, device: &B::Device) -> (Tensor<B, 4>, Tensor<B, 4>) {
    let gx: Vec<f32> = (0..h * w).map(|i| (i % w) as f32).collect();
    let gy: Vec<f32> = (0..h * w).map(|i| (i / w) as f32).collect();
    (
        Tensor::from_data(TensorData::new(gx, [1, 1, h, w]), device),
        Tensor::from_data(TensorData::new(gy, [1, 1, h, w]), device),
    )
}

impl<B: Backend> AdaptiveGroupCorrelation<B> {
    fn group_mean(&self, prod: Tensor<B, 5>) -> Tensor<B, 5> {
        // prod: (N, K, H, W, C) -> (N, K, H, W, G)
        let [n, k, h, w, c] = prod.dims();
        let g = self.groups;
        prod.reshape([n, k, h, w, g, c / g])
            .mean_dim(5)
            .reshape([n, k, h, w, g])
    }

    /// The 1/16 cross-attention step: left attends right, then right attends the updated left.
    /// Returns the attended maps as tokens (N, H·W, C).
    pub fn cross_attend(&self, layer: &LoFTREncoderLayer<B>) -> (Tensor<B, 3>, Tensor<B, 3>) {
        layer.forward_cross(to_tokens(self.fmap1.clone()), to_tokens(self.fmap2.clone()))
    }

    /// Offset correlation (1/16 with `att = Some(cross attention)`, 1/8 with `None`).
    ///
    /// `flow`: (N, 2, H, W) (x, y); `extra_offset`: (N, 18, H, W), channel `2k` = x and `2k+1` = y
    /// offset of candidate `k`. Returns (N, groups·9, H, W).
    pub fn corr_offset(
        &self,
        flow: Tensor<B, 4>,
        extra_offset: Tensor<B, 4>,
        window: SearchWindow,
        att: Option<&LoFTREncoderLayer<B>>,
    ) -> Tensor<B, 4> {
        let [_, _, h, w] = self.fmap1.dims();
        match att {
            Some(layer) => {
                let (l, r) = self.cross_attend(layer);
                self.corr_offset_maps(
                    from_tokens(l, h, w),
                    from_tokens(r, h, w),
                    flow,
                    extra_offset,
                    window,
                )
            }
            None => self.corr_offset_maps(
                self.fmap1.clone(),
                self.fmap2.clone(),
                flow,
                extra_offset,
                window,
            ),
        }
    }

    /// Offset correlation between explicit `left` / `right` maps of this level's shape.
    pub fn corr_offset_maps(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        flow: Tensor<B, 4>,
        extra_offset: Tensor<B, 4>,
        window: SearchWindow,
    ) -> Tensor<B, 4> {
        let [n, c, h, w] = left.dims();
        let device = left.device();
        let offsets = window.offsets();
        let k = offsets.len();
        assert_eq!(extra_offset.dims(), [n, 2 * k, h, w], "AGCL: offset shape");
        let extra = extra_offset.reshape([n, k, 2, h, w]);
        let off_x = extra
            .clone()
            .slice([0..n, 0..k, 0..1, 0..h, 0..w])
            .reshape([n, k, h, w]);
        let off_y = extra
            .slice([0..n, 0..k, 1..2, 0..h, 0..w])
            .reshape([n, k, h, w]);
        let dx: Vec<f32> = offsets.iter().map(|o| o.0 as f32).collect();
        let dy: Vec<f32> = offsets.iter().map(|o| o.1 as f32).collect();
        let dx = Tensor::<B, 4>::from_data(TensorData::new(dx, [1, k, 1, 1]), &device);
        let dy = Tensor::<B, 4>::from_data(TensorData::new(dy, [1, k, 1, 1]), &device);
        let (gx, gy) = pixel_grid::<B>(h, w, &device);
        let fx = flow.clone().slice([0..n, 0..1, 0..h, 0..w]);
        let fy = flow.slice([0..n, 1..2, 0..h, 0..w]);
        let x = (gx + fx + dx + off_x).reshape([n, k * h * w]);
        let y = (gy + fy + dy + off_y).reshape([n, k * h * w]);
        let sampled = bilinear_sample_points(right, x, y).reshape([n, k, h, w, c]);
        let left = left.permute([0, 2, 3, 1]).reshape([n, 1, h, w, c]);
        let corr = self.group_mean(left * sampled); // n k h w g
        corr.permute([0, 4, 1, 2, 3])
            .reshape([n, self.groups * k, h, w])
    }

    /// Warp-and-shift correlation used at 1/4 (no learned offsets).
    pub fn corr_warp(&self, flow: Tensor<B, 4>, window: SearchWindow) -> Tensor<B, 4> {
        let [n, c, h, w] = self.fmap1.dims();
        let device = self.fmap1.device();
        let (gx, gy) = pixel_grid::<B>(h, w, &device);
        let fx = flow.clone().slice([0..n, 0..1, 0..h, 0..w]);
        let fy = flow.slice([0..n, 1..2, 0..h, 0..w]);
        let x = (gx + fx).reshape([n, h * w]);
        let y = (gy + fy).reshape([n, h * w]);
        let warped = bilinear_sample_points(self.fmap2.clone(), x, y) // n hw c
            .reshape([n, h, w, c])
            .permute([0, 3, 1, 2]);
        let (ry, rx) = window.radius();
        let padded = warped.pad((rx, rx, ry, ry), PadMode::Edge);
        let g = self.groups;
        let mut corrs = Vec::new();
        for (dx, dy) in window.offsets() {
            let oy = (dy + ry as i64) as usize;
            let ox = (dx + rx as i64) as usize;
            let crop = padded.clone().slice([0..n, 0..c, oy..oy + h, ox..ox + w]);
            let prod = (self.fmap1.clone() * crop).reshape([n, g, c / g, h, w]);
            corrs.push(prod.mean_dim(2)); // n g 1 h w
        }
        Tensor::cat(corrs, 2).reshape([n, g * window.offsets().len(), h, w])
    }
}
