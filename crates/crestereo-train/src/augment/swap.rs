//! Swapping the views: the right view, mirrored, becomes a left view.

use stereo_io::DisparityMap;

use super::BgrImage;

/// Mirrors an image left to right.
pub fn mirror_image(img: &BgrImage) -> BgrImage {
    let mut out = img.clone();
    for row in out.data.chunks_exact_mut(img.width) {
        row.reverse();
    }
    out
}

/// Mirrors a disparity map left to right (values and validity).
pub fn mirror_disparity(disp: &DisparityMap) -> DisparityMap {
    let mut out = disp.clone();
    for row in out.data.chunks_exact_mut(disp.width) {
        row.reverse();
    }
    for row in out.valid.chunks_exact_mut(disp.width) {
        row.reverse();
    }
    out
}

/// A pair after [`swap_and_mirror`].
#[derive(Debug, Clone, PartialEq)]
pub struct Swapped {
    /// The mirrored right image.
    pub left: BgrImage,
    /// The mirrored left image.
    pub right: BgrImage,
    /// The mirrored right-view disparity: the new left view's.
    pub disp: DisparityMap,
}

/// Makes the right view the left one.
///
/// Mirroring is what keeps disparities positive: a right-view pixel at `x_r` sees its match at
/// `x_r + d` in the left image; after mirroring both, the new left pixel `W−1−x_r` finds it at
/// `W−1−x_r − d` in the new right image, so the right-view disparity, mirrored, is exactly the
/// new left-view disparity with `x_right = x_left − d`.
pub fn swap_and_mirror(left: &BgrImage, right: &BgrImage, disp_right: &DisparityMap) -> Swapped {
    Swapped {
        left: mirror_image(right),
        right: mirror_image(left),
        disp: mirror_disparity(disp_right),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::augment::test_support::*;

    #[test]
    fn swap_and_mirror_keeps_the_pair_consistent() {
        let scene = two_plane_scene(W, H);
        let (left, right) = (
            BgrImage::from_rgb(&scene.left),
            BgrImage::from_rgb(&scene.right),
        );
        let disp_right = scene.disp_right.as_ref().unwrap();
        let Swapped {
            left: new_left,
            right: new_right,
            disp: new_disp,
        } = swap_and_mirror(&left, &right, disp_right);
        assert_eq!(at(&new_left, 2, 0, 3), at(&right, 2, W - 1, 3));
        assert_eq!(new_disp.valid, mirror_disparity(disp_right).valid);
        let swapped = train_sample_of(new_left, new_right, new_disp);
        assert!(assert_consistent(&swapped, 0.0) > W * H / 2);
    }
}
