//! The parallel stereo rig and its pinhole intrinsics: the one place the camera formulas live.
//!
//! Image coordinates are continuous: x right, y down, the top-left corner of the top-left pixel
//! at (0, 0), so pixel (i, j) has its centre at (i + 0.5, j + 0.5) and the principal point of a
//! W×H image is (W/2, H/2). OpenCV-style K matrices (pixel centres at integers) use cx − 0.5.

use serde::{Deserialize, Serialize};

/// Two identical pinhole cameras side by side, looking down −Z with +Y up (Blender's camera
/// convention), centred on the origin: left at (−B/2, 0, 0), right at (+B/2, 0, 0).
/// The sensor fits horizontally and pixels are square, so `f_px` applies to both axes.
/// [`StereoRig::cameras`] derives what a renderer needs to reproduce it.
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

    /// Principal point in continuous image coordinates (see the module docs): the image centre.
    pub fn principal_point(&self) -> (f64, f64) {
        (f64::from(self.width) / 2.0, f64::from(self.height) / 2.0)
    }

    /// Blender's lens shift (`shift_x`, `shift_y`) that puts the principal point where
    /// [`Self::principal_point`] says. With a horizontal sensor fit Blender measures shift in image
    /// widths, and a positive shift moves the view right (x) or up (y): cx = W/2 − shift_x·W,
    /// cy = H/2 + shift_y·W.
    pub fn blender_shift(&self) -> (f64, f64) {
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let (cx, cy) = self.principal_point();
        ((w / 2.0 - cx) / w, (cy - h / 2.0) / w)
    }

    /// The derived camera facts a renderer copies instead of re-deriving them.
    pub fn cameras(&self) -> StereoCameras {
        let (cx, cy) = self.principal_point();
        let (shift_x, shift_y) = self.blender_shift();
        let view = |v| ViewCamera {
            position: [self.camera_x(v), 0.0, 0.0],
            rotation: [0.0; 3],
        };
        StereoCameras {
            f_px: self.f_px(),
            principal_point: [cx, cy],
            image_coordinates: ImageCoordinates::PixelCornerOrigin,
            left: view(View::Left),
            right: view(View::Right),
            blender: BlenderCamera {
                lens_mm: self.focal_mm,
                sensor_width_mm: self.sensor_width_mm,
                sensor_fit: SensorFit::Horizontal,
                shift_x,
                shift_y,
            },
        }
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
        [
            (u - cx) * z / f + self.camera_x(View::Left),
            -(v - cy) * z / f,
            -z,
        ]
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

/// The camera facts of a rig, written into every SceneSpec (`cameras`) so the renderer copies them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereoCameras {
    /// Focal length in pixels, both axes (square pixels).
    pub f_px: f64,
    /// (cx, cy) in `image_coordinates`.
    pub principal_point: [f64; 2],
    pub image_coordinates: ImageCoordinates,
    pub left: ViewCamera,
    pub right: ViewCamera,
    pub blender: BlenderCamera,
}

impl StereoCameras {
    /// Equal up to float noise (1e-9 relative): the facts of a spec read back from JSON.
    pub fn agrees_with(&self, other: &StereoCameras) -> bool {
        let numbers = |c: &StereoCameras| {
            let b = &c.blender;
            let mut v = vec![c.f_px, b.lens_mm, b.sensor_width_mm, b.shift_x, b.shift_y];
            v.extend(c.principal_point);
            v.extend(
                c.left
                    .position
                    .iter()
                    .chain(&c.left.rotation)
                    .chain(&c.right.position)
                    .chain(&c.right.rotation),
            );
            v
        };
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0);
        self.image_coordinates == other.image_coordinates
            && self.blender.sensor_fit == other.blender.sensor_fit
            && numbers(self)
                .iter()
                .zip(&numbers(other))
                .all(|(a, b)| close(*a, *b))
    }
}

/// How image positions are measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageCoordinates {
    /// Continuous, x right, y down, (0, 0) at the top-left corner of the top-left pixel, pixel
    /// centres at +0.5.
    PixelCornerOrigin,
}

/// Pose of one camera in rig space (metres; XYZ Euler radians; zero rotation looks down −Z, +Y up).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewCamera {
    pub position: [f64; 3],
    pub rotation: [f64; 3],
}

/// Blender camera data that gives the rig's intrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlenderCamera {
    pub lens_mm: f64,
    pub sensor_width_mm: f64,
    pub sensor_fit: SensorFit,
    pub shift_x: f64,
    pub shift_y: f64,
}

/// Blender's `sensor_fit`, spelled as Blender spells it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SensorFit {
    /// The sensor width maps to the image width.
    #[serde(rename = "HORIZONTAL")]
    Horizontal,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> StereoRig {
        StereoRig {
            width: 320,
            height: 240,
            focal_mm: 35.0,
            sensor_width_mm: 36.0,
            baseline_m: 0.1,
        }
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

    #[test]
    fn cameras_restate_the_rig() {
        let r = rig();
        let c = r.cameras();
        assert_eq!(c.left.position, [-0.05, 0.0, 0.0]);
        assert_eq!(c.right.position, [0.05, 0.0, 0.0]);
        assert_eq!(c.principal_point, [160.0, 120.0]);
        assert_eq!((c.blender.shift_x, c.blender.shift_y), (0.0, 0.0));
        assert_eq!(c.f_px, r.f_px());
        // A point on the optical axis of a view projects to the principal point.
        let (u, v) = r
            .project(View::Right, [c.right.position[0], 0.0, -3.0])
            .unwrap();
        assert_eq!([u, v], c.principal_point);
    }
}
