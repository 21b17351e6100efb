//! An occluding box on the right image.

use serde::{Deserialize, Serialize};

use super::BgrImage;

/// An occluding box on the right image, placed after resizing and cropping.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OcclusionBox {
    /// Half height and half width `[y, x]` in pixels as drawn; truncated to whole pixels and
    /// limited to half the image when applied.
    pub half_size: [f64; 2],
    /// Where the centre lies among the positions that keep the box inside the image,
    /// fractions `[y, x]` in `[0, 1)`.
    pub centre_frac: [f64; 2],
}

impl OcclusionBox {
    /// The box as `[top, bottom, left, right]` (ends exclusive) in a `height × width` image.
    pub fn rect(&self, height: usize, width: usize) -> [usize; 4] {
        let span = |half: f64, frac: f64, size: usize| {
            let half = (half.max(0.0) as usize).min(size / 2);
            let room = size - 2 * half;
            let centre = half + ((frac * room as f64) as usize).min(room.saturating_sub(1));
            (centre - half, centre + half)
        };
        let (top, bottom) = span(self.half_size[0], self.centre_frac[0], height);
        let (left, right) = span(self.half_size[1], self.centre_frac[1], width);
        [top, bottom, left, right]
    }
}

/// Paints the box with the image's own mean colour (taken over the whole image, padding
/// included, as in the reference). Only the right image gets it: left-view ground truth stays
/// meaningful while the network learns to fill in matches it cannot see.
pub fn occlude_right(img: &mut BgrImage, occlusion: &OcclusionBox) {
    let (width, height) = (img.width, img.height);
    let [top, bottom, left, right] = occlusion.rect(height, width);
    for channel in 0..3 {
        let plane = img.plane_mut(channel);
        let mean =
            (plane.iter().map(|&v| f64::from(v)).sum::<f64>() / plane.len().max(1) as f64) as f32;
        for y in top..bottom {
            plane[y * width + left..y * width + right].fill(mean);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::augment::test_support::*;

    #[test]
    fn occlusion_fills_a_box_with_the_mean_colour() {
        let img = noise_image();
        let mut out = img.clone();
        let occlusion = OcclusionBox {
            half_size: [10.7, 12.2],
            centre_frac: [0.5, 0.25],
        };
        // Half sizes truncate to 10 and 12; centre row 10 + ⌊0.5·12⌋ = 16, column 12 + ⌊0.25·24⌋ = 18.
        assert_eq!(occlusion.rect(H, W), [6, 26, 6, 30]);
        occlude_right(&mut out, &occlusion);
        for c in 0..3 {
            let mean = img.plane(c).iter().sum::<f32>() / (W * H) as f32;
            for y in 0..H {
                for x in 0..W {
                    if (6..26).contains(&y) && (6..30).contains(&x) {
                        assert!((at(&out, c, x, y) - mean).abs() < 1e-3);
                    } else {
                        assert_eq!(at(&out, c, x, y), at(&img, c, x, y));
                    }
                }
            }
        }
        // A box larger than the image covers it exactly, never beyond.
        let huge = OcclusionBox {
            half_size: [50.0, 99.0],
            centre_frac: [0.9, 0.1],
        };
        assert_eq!(huge.rect(H, W), [0, H, 0, W]);
    }
}
