//! Cutting (or zero-padding) the training window.

use stereo_io::DisparityMap;

use super::BgrImage;

/// Offset of a `crop`-long window in a `size`-long axis: among the `|size − crop| + 1` possible
/// positions, the one at fraction `frac`. Negative when the image is smaller than the crop: the
/// image then sits at `−offset` inside a zero canvas, at a random place as in the reference.
pub fn crop_offset(size: usize, crop: usize, frac: f64) -> isize {
    let excess = size as isize - crop as isize;
    let positions = excess.unsigned_abs() + 1;
    let pick = ((frac.clamp(0.0, 1.0) * positions as f64) as usize).min(positions - 1);
    excess.min(0) + pick as isize
}

/// For output index `i` of a window starting at `offset`, the source index if it is inside.
fn inside(i: usize, offset: isize, size: usize) -> Option<usize> {
    let s = i as isize + offset;
    (0..size as isize).contains(&s).then_some(s as usize)
}

/// The `crop = [height, width]` window whose top-left corner is at (`top`, `left`) in the
/// image; pixels outside the image are 0.
pub fn crop_image(img: &BgrImage, top: isize, left: isize, crop: [usize; 2]) -> BgrImage {
    let [out_h, out_w] = crop;
    let mut out = BgrImage::zeros(out_w, out_h);
    for channel in 0..3 {
        let src = img.plane(channel);
        let dst = out.plane_mut(channel);
        for y in 0..out_h {
            let Some(sy) = inside(y, top, img.height) else {
                continue;
            };
            for x in 0..out_w {
                if let Some(sx) = inside(x, left, img.width) {
                    dst[y * out_w + x] = src[sy * img.width + sx];
                }
            }
        }
    }
    out
}

/// The same window of a disparity map; outside the map, disparity 0 and invalid.
pub fn crop_disparity(
    disp: &DisparityMap,
    top: isize,
    left: isize,
    crop: [usize; 2],
) -> DisparityMap {
    let [out_h, out_w] = crop;
    let mut out = DisparityMap::new(out_w, out_h);
    for y in 0..out_h {
        let Some(sy) = inside(y, top, disp.height) else {
            continue;
        };
        for x in 0..out_w {
            if let Some(sx) = inside(x, left, disp.width) {
                out.data[y * out_w + x] = disp.data[sy * disp.width + sx];
                out.valid[y * out_w + x] = disp.valid[sy * disp.width + sx];
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
    fn crop_has_the_requested_size_and_stays_inside() {
        let img = noise_image();
        for frac in [0.0, 0.3, 0.999_999] {
            let top = crop_offset(H, 16, frac);
            let left = crop_offset(W, 20, frac);
            assert!((0..=(H - 16) as isize).contains(&top), "top {top}");
            assert!((0..=(W - 20) as isize).contains(&left), "left {left}");
            let out = crop_image(&img, top, left, [16, 20]);
            assert_eq!((out.height, out.width), (16, 20));
            assert_eq!(at(&out, 1, 0, 0), at(&img, 1, left as usize, top as usize));
            assert_eq!(
                at(&out, 2, 19, 15),
                at(&img, 2, left as usize + 19, top as usize + 15)
            );
        }
        assert_eq!(
            crop_offset(H, 16, 0.999_999),
            16,
            "the last position is reachable"
        );
        assert_eq!(crop_offset(H, H, 0.7), 0);
    }
}
