//! The parallel stereo rig and its pinhole intrinsics: the one place the camera formulas live.

use serde::{Deserialize, Serialize};

/// Two identical pinhole cameras side by side, looking down −Z with +Y up (Blender's camera
/// convention), centred on the origin: left at (−B/2, 0, 0), right at (+B/2, 0, 0).
/// The sensor fits horizontally and pixels are square, so `f_px` applies to both axes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereoRig {
    pub width: u32,
    pub height: u32,
    pub focal_mm: f64,
    pub sensor_width_mm: f64,
    pub baseline_m: f64,
}

impl StereoRig {
    /// Focal length in pixels.
    pub fn f_px(&self) -> f64 {
        self.focal_mm / self.sensor_width_mm * f64::from(self.width)
    }

    /// Principal point (the image centre; Blender's shift is kept at 0).
    pub fn principal_point(&self) -> (f64, f64) {
        (f64::from(self.width) / 2.0, f64::from(self.height) / 2.0)
    }

    /// Disparity of a point at planar depth `z` (metres, positive in front of the rig).
    pub fn disparity_at_depth(&self, z: f64) -> f64 {
        self.f_px() * self.baseline_m / z
    }

    /// Planar depth that produces disparity `d` (pixels).
    pub fn depth_for_disparity(&self, d: f64) -> f64 {
        self.f_px() * self.baseline_m / d
    }

    /// Camera centre of a view in rig coordinates.
    pub fn camera_x(&self, view: View) -> f64 {
        match view {
            View::Left => -self.baseline_m / 2.0,
            View::Right => self.baseline_m / 2.0,
        }
    }

    /// Projects a rig-space point into a view: (column, row) in pixels from the top-left
    /// corner of the image, pixel centres at +0.5. `None` behind the camera.
    pub fn project(&self, view: View, p: [f64; 3]) -> Option<(f64, f64)> {
        let z = -p[2];
        if z <= 0.0 {
            return None;
        }
        let (cx, cy) = self.principal_point();
        let f = self.f_px();
        Some((cx + f * (p[0] - self.camera_x(view)) / z, cy - f * p[1] / z))
    }

    /// The rig-space point seen at left-image position (u, v) at planar depth `z`.
    pub fn unproject_left(&self, u: f64, v: f64, z: f64) -> [f64; 3] {
        let (cx, cy) = self.principal_point();
        let f = self.f_px();
        [(u - cx) * z / f + self.camera_x(View::Left), -(v - cy) * z / f, -z]
    }

    /// Unit-less ray direction through pixel position (u, v) of a view (not normalised, z = −1).
    pub fn ray_direction(&self, u: f64, v: f64) -> [f64; 3] {
        let (cx, cy) = self.principal_point();
        let f = self.f_px();
        [(u - cx) / f, -(v - cy) / f, -1.0]
    }
}

/// Which camera of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum View {
    Left,
    Right,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> StereoRig {
        StereoRig { width: 320, height: 240, focal_mm: 35.0, sensor_width_mm: 36.0, baseline_m: 0.1 }
    }

    #[test]
    fn projection_gives_the_rig_disparity() {
        let r = rig();
        let p = r.unproject_left(100.25, 50.5, 2.5);
        let (ul, vl) = r.project(View::Left, p).unwrap();
        let (ur, vr) = r.project(View::Right, p).unwrap();
        assert!((ul - 100.25).abs() < 1e-9 && (vl - 50.5).abs() < 1e-9 && (vr - vl).abs() < 1e-12);
        assert!((ul - ur - r.disparity_at_depth(2.5)).abs() < 1e-9);
        assert!((r.depth_for_disparity(r.disparity_at_depth(2.5)) - 2.5).abs() < 1e-12);
    }
}
