//! Resizing images and disparity by one factor.

use stereo_io::DisparityMap;

use super::BgrImage;

/// Size of a `height × width` image resized by `scale`, rounded like OpenCV's `fx`/`fy` resize.
pub fn scaled_size(height: usize, width: usize, scale: f64) -> (usize, usize) {
    let size = |n: usize| ((n as f64 * scale).round() as usize).max(1);
    (size(height), size(width))
}

/// Source coordinate of output pixel `i` with pixel centres aligned (`(i + 0.5)/s − 0.5`),
/// the mapping of OpenCV's resize; the image's content scales by exactly `scale` about the
/// image corner, whatever rounding the output size gets.
fn source_coordinate(i: usize, scale: f64) -> f64 {
    (i as f64 + 0.5) / scale - 0.5
}

/// Bilinear resize by `scale` with edge pixels repeated (OpenCV `INTER_LINEAR`).
pub fn rescale_image(img: &BgrImage, scale: f64) -> BgrImage {
    let (out_h, out_w) = scaled_size(img.height, img.width, scale);
    let taps = |out_n: usize, in_n: usize| -> Vec<(usize, usize, f32)> {
        (0..out_n)
            .map(|i| {
                let s = source_coordinate(i, scale).clamp(0.0, (in_n - 1) as f64);
                let i0 = s.floor() as usize;
                let i1 = (i0 + 1).min(in_n - 1);
                (i0, i1, (s - i0 as f64) as f32)
            })
            .collect()
    };
    let x_taps = taps(out_w, img.width);
    let y_taps = taps(out_h, img.height);
    let mut out = BgrImage::zeros(out_w, out_h);
    for channel in 0..3 {
        let src = img.plane(channel);
        let dst = out.plane_mut(channel);
        for (y, &(y0, y1, fy)) in y_taps.iter().enumerate() {
            let (row0, row1) = (&src[y0 * img.width..], &src[y1 * img.width..]);
            for (x, &(x0, x1, fx)) in x_taps.iter().enumerate() {
                let top = row0[x0] * (1.0 - fx) + row0[x1] * fx;
                let bottom = row1[x0] * (1.0 - fx) + row1[x1] * fx;
                dst[y * out_w + x] = top * (1.0 - fy) + bottom * fy;
            }
        }
    }
    out
}

/// Resizes a disparity map by `scale` and multiplies the values by it.
///
/// Validity is decided at the original resolution, `valid && 0 < d < max_disp / scale` (so
/// `d < max_disp` after resizing), as the reference does. Values and validity are then taken
/// from the nearest source pixel, the one whose area contains the image's bilinear sample
/// point: blending would average foreground and background at depth edges into a disparity
/// no surface has, and a bilinearly resized mask would be fractional.
pub fn rescale_disparity(disp: &DisparityMap, scale: f64, max_disp: f64) -> DisparityMap {
    let limit = max_disp / scale;
    let in_range = |i: usize| {
        let d = f64::from(disp.data[i]);
        disp.valid[i] && d.is_finite() && d > 0.0 && d < limit
    };
    let (out_h, out_w) = scaled_size(disp.height, disp.width, scale);
    let nearest = |out_i: usize, in_n: usize| {
        ((source_coordinate(out_i, scale) + 0.5).max(0.0) as usize).min(in_n - 1)
    };
    let x_src: Vec<usize> = (0..out_w).map(|x| nearest(x, disp.width)).collect();
    let mut out = DisparityMap::new(out_w, out_h);
    for y in 0..out_h {
        let row = nearest(y, disp.height) * disp.width;
        for (x, &sx) in x_src.iter().enumerate() {
            let i = row + sx;
            if in_range(i) {
                out.data[y * out_w + x] = (f64::from(disp.data[i]) * scale) as f32;
                out.valid[y * out_w + x] = true;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::augment::test_support::*;

    #[test]
    fn rescale_scales_disparity_and_keeps_the_pair_matched() {
        let d = 10;
        let left = noise_image();
        // x_right = x_left − d, so the right image at x shows the left image's x + d.
        let right = planar_from_fn(W, H, |c, x, y| noise(x as i64 + d, y as i64, c as u64));
        let disp = constant_disparity(W, H, d as f32);
        let scale = 0.8;
        let (l, r) = (rescale_image(&left, scale), rescale_image(&right, scale));
        let sd = rescale_disparity(&disp, scale, 256.0);
        assert_eq!((l.height, l.width), (26, 38));
        assert_eq!((sd.height, sd.width), (26, 38));
        let shifted = 8; // s·d
        for y in 0..l.height {
            for x in shifted..l.width {
                assert!(sd.is_valid(x, y));
                assert!(
                    (sd.get(x, y) - 8.0).abs() < 1e-5,
                    "disparity {}",
                    sd.get(x, y)
                );
                for c in 0..3 {
                    let (a, b) = (at(&l, c, x, y), at(&r, c, x - shifted, y));
                    assert!(
                        (a - b).abs() < 1e-3,
                        "({x},{y})[{c}]: left {a} vs right {b}"
                    );
                }
            }
        }
        // The textures really differ a pixel off, so the check above can fail.
        assert!((at(&l, 0, 20, 10) - at(&r, 0, 20 - shifted + 1, 10)).abs() > 1.0);
    }

    #[test]
    fn rescale_by_one_is_the_identity() {
        let img = noise_image();
        assert_eq!(rescale_image(&img, 1.0), img);
        let scene = two_plane_scene(W, H);
        let disp = rescale_disparity(&scene.disp_left, 1.0, 256.0);
        assert!(disp.valid == scene.disp_left.valid, "validity changed");
        for (i, &v) in disp.valid.iter().enumerate() {
            if v {
                assert_eq!(disp.data[i], scene.disp_left.data[i]);
            } else {
                assert_eq!(disp.data[i], 0.0, "invalid pixels hold 0");
            }
        }
    }

    #[test]
    fn validity_threshold_is_max_disp_over_scale_before_resizing() {
        let mut disp = DisparityMap::new(4, 1);
        disp.data = vec![300.0, 600.0, 0.0, f32::INFINITY];
        disp.valid = vec![true; 4];
        // Scale 0.5: the limit is 256 / 0.5 = 512 at the original resolution.
        let mut wide = DisparityMap::new(8, 2);
        for y in 0..2 {
            for x in 0..8 {
                wide.data[y * 8 + x] = disp.data[x / 2];
                wide.valid[y * 8 + x] = true;
            }
        }
        let half = rescale_disparity(&wide, 0.5, 256.0);
        assert_eq!(half.width, 4);
        assert_eq!(half.valid, vec![true, false, false, false]);
        assert_eq!(half.data[0], 150.0);
        // At scale 1 the same 300 px is beyond 256.
        let same = rescale_disparity(&disp, 1.0, 256.0);
        assert_eq!(same.valid, vec![false; 4]);
        // A pixel the dataset marks invalid stays invalid whatever its value.
        disp.valid[0] = false;
        assert!(!rescale_disparity(&disp, 1.0, 1000.0).valid[0]);
    }

    #[test]
    fn rescaled_disparity_never_blends_across_a_depth_edge() {
        let scene = two_plane_scene(W, H);
        for scale in [0.6, 0.73, 0.9] {
            let out = rescale_disparity(&scene.disp_left, scale, 256.0);
            for (&d, &v) in out.data.iter().zip(&out.valid) {
                if v {
                    let original = d as f64 / scale;
                    assert!(
                        (original - BACK as f64).abs() < 1e-4
                            || (original - FRONT as f64).abs() < 1e-4,
                        "disparity {d} at scale {scale} belongs to no surface"
                    );
                }
            }
        }
    }

    #[test]
    fn rescaled_disparity_takes_the_pixel_under_the_image_sample_point() {
        // Column c holds c + 1, so each output value names its source column.
        let mut disp = DisparityMap::new(8, 1);
        disp.data = (1..=8).map(|c| c as f32).collect();
        disp.valid = vec![true; 8];
        // At scale 0.75 output x samples the image at (x + 0.5)/0.75 − 0.5 =
        // 0.17, 1.5, 2.83, 4.17, 5.5, 6.83: nearest columns 0, 2 (tie upwards), 3, 4, 6, 7.
        let out = rescale_disparity(&disp, 0.75, 1e9);
        let sources: Vec<f32> = out.data.iter().map(|d| d / 0.75 - 1.0).collect();
        assert_eq!(sources, vec![0.0, 2.0, 3.0, 4.0, 6.0, 7.0]);
    }
}
