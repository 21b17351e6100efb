//! The right image's rectification error: a slight rotation and a vertical shift.

use serde::{Deserialize, Serialize};

use super::BgrImage;

/// Rotation about a point and vertical shift of the right image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RightWarp {
    /// Counter-clockwise as seen on screen (OpenCV's `getRotationMatrix2D` convention).
    pub angle_deg: f64,
    /// Rotation centre as fractions `[y, x]` of the image's height and width, in `[0, 1)`.
    pub centre_frac: [f64; 2],
    /// Positive moves the content down: output row `r` shows input row `r − shift_y`.
    pub shift_y: f64,
}

/// The four bilinear taps around continuous pixel coordinates (`x`, `y`) as (index, weight);
/// taps outside the image are `None` and count as 0, so content fades to black at the border
/// like OpenCV's constant-border warp.
fn bilinear_taps(width: usize, height: usize, x: f64, y: f64) -> [(Option<usize>, f32); 4] {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let index = |xi: f64, yi: f64| {
        let inside = xi >= 0.0 && yi >= 0.0 && xi < width as f64 && yi < height as f64;
        inside.then(|| yi as usize * width + xi as usize)
    };
    [
        (index(x0, y0), (1.0 - fx) * (1.0 - fy)),
        (index(x0 + 1.0, y0), fx * (1.0 - fy)),
        (index(x0, y0 + 1.0), (1.0 - fx) * fy),
        (index(x0 + 1.0, y0 + 1.0), fx * fy),
    ]
}

/// Rotates the (right) image about `warp`'s centre, then shifts it vertically; bilinear, black
/// where nothing maps. Only the right image is warped, so the left-view ground truth stays
/// exact while the pair stops being perfectly rectified.
pub fn warp_right(img: &BgrImage, warp: &RightWarp) -> BgrImage {
    let (sin, cos) = warp.angle_deg.to_radians().sin_cos();
    let centre_y = warp.centre_frac[0] * img.height as f64;
    let centre_x = warp.centre_frac[1] * img.width as f64;
    remap(img, |x, y| {
        // The forward map rotates by +angle (on screen) and then shifts; undo both to find
        // where an output pixel comes from.
        let u = x - centre_x;
        let v = y - warp.shift_y - centre_y;
        (cos * u - sin * v + centre_x, sin * u + cos * v + centre_y)
    })
}

/// The image resampled through `source`, which gives for an output pixel's (x, y) the
/// continuous input position it shows; bilinear, black where that falls outside the image.
pub fn remap(img: &BgrImage, source: impl Fn(f64, f64) -> (f64, f64)) -> BgrImage {
    let (width, height) = (img.width, img.height);
    let plane_len = width * height;
    let mut out = BgrImage::zeros(width, height);
    for y in 0..height {
        for x in 0..width {
            let (sx, sy) = source(x as f64, y as f64);
            // The taps serve all three channels.
            let taps = bilinear_taps(width, height, sx, sy);
            for channel in 0..3 {
                let src = &img.data[channel * plane_len..(channel + 1) * plane_len];
                out.data[channel * plane_len + y * width + x] = taps
                    .iter()
                    .map(|&(i, w)| i.map_or(0.0, |i| src[i] * w))
                    .sum();
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::augment::test_support::*;

    /// A warp that shifts rows by `shift_y` and turns nothing.
    fn shift_only(centre_frac: [f64; 2], shift_y: f64) -> RightWarp {
        RightWarp {
            angle_deg: 0.0,
            centre_frac,
            shift_y,
        }
    }

    #[test]
    fn vertical_shift_of_one_pixel_moves_rows_down() {
        let img = noise_image();
        let warp = shift_only([0.3, 0.7], 1.0);
        let out = warp_right(&img, &warp);
        for c in 0..3 {
            for x in 0..W {
                assert_eq!(at(&out, c, x, 0), 0.0, "nothing maps to the top row");
                for y in 1..H {
                    assert_eq!(at(&out, c, x, y), at(&img, c, x, y - 1));
                }
            }
        }
    }

    #[test]
    fn warp_without_rotation_or_shift_is_the_identity() {
        let img = noise_image();
        let warp = shift_only([0.25, 0.9], 0.0);
        assert_eq!(warp_right(&img, &warp), img);
    }

    #[test]
    fn rotation_moves_content_right_of_the_centre_upwards() {
        // A linear image, so bilinear sampling is exact and the expected value is analytic.
        let ramp = |x: f64, y: f64| 20.0 + 0.5 * x + 3.0 * y;
        let img = planar_from_fn(W, H, |_, x, y| ramp(x as f64, y as f64) as f32);
        let angle: f64 = 5.0;
        let warp = RightWarp {
            angle_deg: angle,
            centre_frac: [0.5, 0.5],
            shift_y: 0.0,
        };
        let out = warp_right(&img, &warp);
        // Centre (24, 16). A counter-clockwise turn lifts the point 16 px right of the centre
        // by 16·sin 5° ≈ 1.39 rows, so output (40, 16) shows what was at (24 + 16 cos, 16 + 16 sin).
        let (sin, cos) = angle.to_radians().sin_cos();
        let expected = ramp(24.0 + 16.0 * cos, 16.0 + 16.0 * sin) as f32;
        let got = at(&out, 1, 40, 16);
        assert!(
            (got - expected).abs() < 1e-3,
            "got {got}, expected {expected}"
        );
        assert!(
            got > at(&img, 1, 40, 16) + 3.0,
            "content should come from lower rows"
        );
        // Left of the centre the opposite: content comes from higher rows.
        assert!(at(&out, 1, 8, 16) < at(&img, 1, 8, 16) - 3.0);
        // Below the centre the turn pushes content to the right: output (24, 26) shows what
        // was at (24 − 10 sin, 16 + 10 cos).
        let expected = ramp(24.0 - 10.0 * sin, 16.0 + 10.0 * cos) as f32;
        let got = at(&out, 1, 24, 26);
        assert!(
            (got - expected).abs() < 1e-3,
            "got {got}, expected {expected}"
        );
        // The centre itself does not move.
        assert!((at(&out, 1, 24, 16) - at(&img, 1, 24, 16)).abs() < 1e-4);
    }
}
