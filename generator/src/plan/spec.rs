//! `SceneSpec`: everything the Blender worker needs to build and render one sample, and nothing
//! it would have to decide itself. Serialised as JSON next to every sample (`<id>.scene.json`).

use serde::{Deserialize, Serialize};

use super::rig::StereoRig;

/// Version of the SceneSpec schema; the worker refuses specs it does not know.
pub const SPEC_FORMAT_VERSION: u32 = 1;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    pub format_version: u32,
    /// File stem of the sample, unique inside its category.
    pub id: String,
    pub category: String,
    pub seed: u64,
    pub index: u64,
    pub rig: StereoRig,
    pub render: RenderSettings,
    pub world: WorldSpec,
    pub objects: Vec<ObjectSpec>,
    pub lights: Vec<LightSpec>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSettings {
    /// Cycles path-tracing samples per pixel (does not affect the depth pass).
    pub samples: u32,
    pub denoise: bool,
    /// Cycles noise seed.
    pub cycles_seed: u32,
    pub max_bounces: u32,
    /// Anti-aliasing filter of the colour pass (the depth pass always samples pixel centres).
    pub pixel_filter: PixelFilter,
    pub filter_width_px: f64,
    /// Camera clipping range in metres.
    pub clip_start: f64,
    pub clip_end: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelFilter {
    BlackmanHarris,
    Gaussian,
    Box,
}

/// Ambient world light (a uniform background colour that also lights the scene).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSpec {
    pub color: [f64; 3],
    pub strength: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    pub name: String,
    pub shape: Shape,
    /// Rig-space location (metres), XYZ Euler rotation (radians), per-axis scale.
    pub location: [f64; 3],
    pub rotation: [f64; 3],
    pub scale: [f64; 3],
    pub material: MaterialSpec,
    /// The disparity the planner aimed this object's centre at (None for backgrounds and
    /// hand-made scenes); kept for distribution checks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_disparity: Option<f64>,
}

/// Geometry in object space; every primitive fits the unit sphere before `scale`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A square in the XY plane, side 2 (−1..1), facing +Z.
    Plane,
    /// Cube with half-size 1/√3 so its corners touch the unit sphere.
    Cube,
    UvSphere { segments: u32, rings: u32 },
    IcoSphere { subdivisions: u32 },
    /// Cylinder along Z, radius and half-height 1/√2.
    Cylinder { vertices: u32 },
    /// Torus in the XY plane; `minor_ratio` = tube radius / ring radius, outer radius 1.
    Torus { major_segments: u32, minor_segments: u32, minor_ratio: f64 },
    /// Explicit triangles (used by exactness tests and any caller that brings its own mesh).
    Mesh { vertices: Vec<[f64; 3]>, triangles: Vec<[u32; 3]> },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MaterialSpec {
    /// One colour everywhere: the textureless case.
    Flat { color: [f64; 3], roughness: f64 },
    /// A procedural Blender texture mapped in object coordinates (works without UVs),
    /// blended between two colours.
    Procedural { pattern: Pattern, scale: f64, color_a: [f64; 3], color_b: [f64; 3], roughness: f64, detail: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Pattern {
    Noise,
    Voronoi,
    Checker,
    Wave,
    Brick,
    Magic,
}

impl Pattern {
    pub const ALL: [Pattern; 6] = [Pattern::Noise, Pattern::Voronoi, Pattern::Checker, Pattern::Wave, Pattern::Brick, Pattern::Magic];
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightSpec {
    /// Omni light; `radius` softens shadows.
    Point { location: [f64; 3], color: [f64; 3], power_w: f64, radius: f64 },
    /// Directional light pointing along −Z rotated by `rotation` (XYZ Euler).
    Sun { rotation: [f64; 3], color: [f64; 3], strength: f64 },
}

impl SceneSpec {
    /// Canonical JSON: the bytes that go to disk and to the worker. Field order is fixed by the
    /// struct definitions and floats print in shortest round-trip form, so equal specs give
    /// equal bytes.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a SceneSpec always serialises")
    }

    pub fn from_json(text: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(text)
    }
}
