//! Image coordinates of a principal point: the two conventions in use, and the one conversion.
//!
//! - **Continuous** (ours: the manifest's `cx`/`cy`, the SceneSpec, Blender; Middlebury/ETH3D
//!   `calib.txt` as cvkit and COLMAP read it): x runs from 0 at
//!   the left edge of the image to W at its right edge; pixel `i` covers `[i, i + 1)` and its
//!   centre is at `i + 0.5`. A centred principal point is `cx = W/2`.
//! - **Pixel centres** (OpenCV `K` matrices, KITTI `P` matrices, and
//!   [`SampleMeta`](crate::SampleMeta)): pixel `i`'s centre is at `x = i`. A centred principal
//!   point is `cx = (W − 1)/2`.
//!
//! Disparities are differences of coordinates and are the same in both.

/// The offset between the conventions: a pixel centre sits half a pixel right of (below) the
/// corner where the continuous coordinate of that pixel starts.
const HALF_PIXEL: f64 = 0.5;

/// A continuous coordinate (ours) in the pixel-centre convention.
pub fn continuous_to_pixel_centres(c: f64) -> f64 {
    c - HALF_PIXEL
}

/// A pixel-centre coordinate in the continuous convention (ours).
pub fn pixel_centres_to_continuous(c: f64) -> f64 {
    c + HALF_PIXEL
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_centre_of_an_image_in_both_conventions() {
        let w = 960.0;
        assert_eq!(continuous_to_pixel_centres(w / 2.0), (w - 1.0) / 2.0);
        assert_eq!(pixel_centres_to_continuous((w - 1.0) / 2.0), w / 2.0);
    }
}
