//! What makes a sample hard to match, measured from its files without a model: the facts a
//! dataset is sliced by (`stereogen stats` per category, a manifest line's `difficulty`).

use serde::{Deserialize, Serialize};

use crate::disparity::{DisparityMap, LEFT_RIGHT_TOLERANCE_PX};
use crate::image_io::RgbImage;

/// A pixel is low-texture where the mean gradient magnitude of the image's luma (0-255, Rec. 601
/// weights; forward differences) over the [`TEXTURE_WINDOW`]-pixel square around it is below
/// this, in levels per pixel: a window a matcher sees no structure in.
pub const LOW_TEXTURE_GRADIENT: f64 = 2.0;
/// Side of the window [`LOW_TEXTURE_GRADIENT`] averages over (px).
pub const TEXTURE_WINDOW: usize = 5;

/// One sample's difficulty facts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Difficulty {
    /// Fraction of the left view's valid pixels that fail the left-right check of the two
    /// ground-truth maps ([`DisparityMap::left_right_consistent`], 1 px): occluded in the right
    /// view or outside it. 0 when the left view has no valid pixel.
    pub occluded: f64,
    /// Fraction of the left image's pixels in low texture ([`LOW_TEXTURE_GRADIENT`]).
    pub low_texture: f64,
    /// 1st and 99th percentiles of the left view's valid disparities (px); 0 without any.
    pub disparity_p1: f32,
    pub disparity_p99: f32,
    /// Fraction of the left image's pixels whose first surface is glass or a mirror-like metal
    /// (a non-zero material pass index, see the generator's `MaterialClass::pass_index`);
    /// absent where the render has no material-index pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transparent_mirror: Option<f64>,
}

impl Difficulty {
    /// Measures a sample: its left image, both views' disparity, and the left view's material
    /// pass index (one value per pixel) where it was rendered.
    pub fn measure(
        left: &RgbImage,
        disp_left: &DisparityMap,
        disp_right: &DisparityMap,
        material_index: Option<&[f32]>,
    ) -> Self {
        let seen = disp_left.left_right_consistent(disp_right, LEFT_RIGHT_TOLERANCE_PX);
        let valid = disp_left.valid.iter().filter(|v| **v).count();
        let occluded = if valid == 0 {
            0.0
        } else {
            (valid - seen.iter().filter(|s| **s).count()) as f64 / valid as f64
        };
        let mut d: Vec<f32> = disp_left
            .data
            .iter()
            .zip(&disp_left.valid)
            .filter(|(_, v)| **v)
            .map(|(d, _)| *d)
            .collect();
        d.sort_unstable_by(f32::total_cmp);
        let rank = |q: f64| d[((d.len() - 1) as f64 * q).round() as usize];
        let (disparity_p1, disparity_p99) = if d.is_empty() {
            (0.0, 0.0)
        } else {
            (rank(0.01), rank(0.99))
        };
        Self {
            occluded,
            low_texture: low_texture_fraction(left),
            disparity_p1,
            disparity_p99,
            transparent_mirror: material_index
                .filter(|m| !m.is_empty())
                .map(|m| m.iter().filter(|i| **i > 0.5).count() as f64 / m.len() as f64),
        }
    }
}

/// Fraction of `img`'s pixels in low texture (see [`LOW_TEXTURE_GRADIENT`]): forward differences
/// of the luma (backward in the last row and column; central ones would not see a one-pixel
/// checkerboard), their magnitude box-averaged over the window (clipped at the border) with a
/// summed-area table.
pub fn low_texture_fraction(img: &RgbImage) -> f64 {
    let (w, h) = (img.width, img.height);
    if w == 0 || h == 0 {
        return 0.0;
    }
    let luma: Vec<f64> = img
        .data
        .chunks_exact(3)
        .map(|p| 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]))
        .collect();
    let at = |x: usize, y: usize| luma[y * w + x];
    // The neighbour pair of a forward difference along an axis of length n at position i
    // (backward at the last position; none on an axis of one pixel).
    let pair = |i: usize, n: usize| {
        if i + 1 < n {
            Some((i, i + 1))
        } else {
            i.checked_sub(1).map(|j| (j, i))
        }
    };
    // Summed-area table of the gradient magnitude, one row and column of zeros in front.
    let mut sat = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            let gx = pair(x, w).map_or(0.0, |(a, b)| at(b, y) - at(a, y));
            let gy = pair(y, h).map_or(0.0, |(a, b)| at(x, b) - at(x, a));
            row += (gx * gx + gy * gy).sqrt();
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let r = TEXTURE_WINDOW / 2;
    let mut low = 0usize;
    for y in 0..h {
        let (ya, yb) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (xa, xb) = (x.saturating_sub(r), (x + r + 1).min(w));
            let sum = sat[yb * (w + 1) + xb] - sat[ya * (w + 1) + xb] - sat[yb * (w + 1) + xa]
                + sat[ya * (w + 1) + xa];
            let mean = sum / ((yb - ya) * (xb - xa)) as f64;
            low += usize::from(mean < LOW_TEXTURE_GRADIENT);
        }
    }
    low as f64 / (w * h) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> RgbImage {
        let mut data = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                data.extend([f(x, y); 3]);
            }
        }
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn flat_is_low_texture_and_a_checkerboard_is_not() {
        assert_eq!(low_texture_fraction(&image(16, 12, |_, _| 128)), 1.0);
        assert_eq!(
            low_texture_fraction(&image(16, 12, |x, y| if (x + y) % 2 == 0 {
                0
            } else {
                255
            })),
            0.0
        );
        // Left half flat, right half a ramp of 10 levels per pixel: the flat half minus the
        // window's reach into the ramp (columns 0-6 of 20).
        let half = image(20, 10, |x, _| {
            if x < 10 {
                50
            } else {
                (50 + 10 * (x - 9)) as u8
            }
        });
        assert!((low_texture_fraction(&half) - 0.35).abs() < 1e-12);
    }

    #[test]
    fn occlusion_is_the_share_of_valid_left_pixels_failing_the_left_right_check() {
        // A 10-px-wide row at disparity 2 everywhere: the two leftmost left pixels match
        // outside the right image.
        let (w, h) = (10, 3);
        let mut left = DisparityMap::new(w, h);
        let mut right = DisparityMap::new(w, h);
        for i in 0..w * h {
            left.data[i] = 2.0;
            left.valid[i] = true;
            right.data[i] = 2.0;
            right.valid[i] = true;
        }
        let img = image(w, h, |_, _| 0);
        let d = Difficulty::measure(&img, &left, &right, None);
        assert!((d.occluded - 0.2).abs() < 1e-12, "{d:?}");
        assert_eq!((d.disparity_p1, d.disparity_p99), (2.0, 2.0));
        // The right view sees another surface where the left's pixel 5 would match.
        for y in 0..h {
            right.data[y * w + 3] = 7.0;
        }
        let d = Difficulty::measure(&img, &left, &right, None);
        assert!((d.occluded - 0.3).abs() < 1e-12, "{d:?}");
        let empty = Difficulty::measure(&img, &DisparityMap::new(w, h), &right, None);
        assert_eq!((empty.occluded, empty.disparity_p99), (0.0, 0.0));
        assert_eq!(empty.transparent_mirror, None);
        // Material indices: 0 everywhere but a glass pixel (1) and a metal pixel (2).
        let mut index = vec![0.0f32; w * h];
        (index[4], index[17]) = (1.0, 2.0);
        let d = Difficulty::measure(&img, &left, &right, Some(&index));
        assert!(
            (d.transparent_mirror.unwrap() - 2.0 / 30.0).abs() < 1e-12,
            "{d:?}"
        );
    }
}
