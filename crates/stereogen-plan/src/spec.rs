//! `SceneSpec`: everything the Blender worker needs to build and render one sample, and nothing
//! it would have to decide itself. Serialised as JSON next to every sample (`<id>.scene.json`).
//!
//! The JSON also carries `cameras`, the camera facts derived from `rig` ([`StereoRig::cameras`]:
//! camera positions, f_px, principal point and its convention, Blender's lens settings), so the
//! worker copies them instead of re-deriving them. They are written from the rig every time and
//! never stored separately: a spec cannot hold facts that disagree with its rig.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

pub use super::render::{
    DenoisePasses, DenoisePrefilter, DenoiseQuality, PixelFilter, RenderSettings,
};
use super::rig::{StereoCameras, StereoRig};

/// Version of the SceneSpec schema. The worker states the version it understands when it starts
/// and is refused there if it differs. Version 3 added `cameras`; version 2 specs (without
/// them) still read, as version 3.
pub const SPEC_FORMAT_VERSION: u32 = 3;

#[derive(Debug, Clone, PartialEq)]
pub struct SceneSpec {
    pub format_version: u32,
    /// File stem of the sample, unique inside its category.
    pub id: String,
    /// Scene category (the recipe category it was drawn from): the sub-folder of the sample.
    pub category: String,
    pub seed: u64,
    pub index: u64,
    pub rig: StereoRig,
    pub render: RenderSettings,
    pub world: WorldSpec,
    pub objects: Vec<ObjectSpec>,
    pub lights: Vec<LightSpec>,
}

/// What fills the view behind the floating objects (a category's `background` weights; how
/// each is built: [`crate::backgrounds`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BackgroundKind {
    Wall,
    Room,
    Environment,
}

/// Uniform world light (background colour that also lights the scene).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSpec {
    pub color: [f64; 3],
    pub strength: f64,
    /// A procedural sky instead of the uniform `color` (an `environment` background).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sky: Option<SkySpec>,
    /// A photographed HDR environment instead of the uniform `color` (an `environment`
    /// background; never beside `sky`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hdri: Option<HdriSpec>,
}

/// The HDR environment maps an `environment` background draws from: the eight Blender ships in
/// its `datafiles/studiolights/world` folder (1024×512 float EXR, CC0, from Poly Haven; part of the
/// pinned `bpy` wheel, so available offline wherever stereogen renders).
pub const STUDIO_HDRIS: [&str; 8] = [
    "city",
    "courtyard",
    "forest",
    "interior",
    "night",
    "studio",
    "sunrise",
    "sunset",
];

/// One of [`STUDIO_HDRIS`] around the scene, turned `rotation` radians about the vertical, at
/// `strength` (its texels' radiance times this). It lights the scene and fills the view where
/// nothing is, as a sky does.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HdriSpec {
    pub name: String,
    pub rotation: f64,
    pub strength: f64,
}

/// Blender's Hosek–Wilkie sky model (analytic): the sun's elevation above the horizon and its
/// rotation about the vertical (radians), the air's turbidity (2 clear .. 10 hazy) and the
/// ground's albedo under the horizon. It lights the scene and fills the view where nothing is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkySpec {
    pub sun_elevation: f64,
    pub sun_rotation: f64,
    pub turbidity: f64,
    pub ground_albedo: f64,
}

/// What the object is for: the background wall, or scene content placed by the disparity law.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectRole {
    Background,
    Content,
}

/// The classes of a dataset's `semantic` maps: class id = position + 1, 0 = no surface. An
/// object's class is what made it (its `source`: the background wall, a primitive, a ShapeNet
/// model, a mesh of the built-in content pack, a room's floor, ceiling or side wall, furniture,
/// an environment's ground, ...); a source not listed (a hand-written spec's)
/// is `other`. New classes go at the end, so ids keep their meaning across versions.
pub const SEMANTIC_CLASSES: [&str; 12] = [
    "wall",
    "primitive",
    "shapenet",
    "meshes",
    "pack",
    "tree",
    "wireframe",
    "net",
    "room",
    "furniture",
    "ground",
    "other",
];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    pub name: String,
    pub role: ObjectRole,
    /// Which shape source made it (primitive, shapenet, meshes, tree, wireframe, net, wall, test).
    pub source: String,
    pub shape: Shape,
    /// Blender modifiers applied in order (wireframe, displacement, subdivision, boolean cut), and
    /// last, where a thing stands on the floor, the drop onto it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub modifiers: Vec<Modifier>,
    /// Rig-space location (metres), XYZ Euler rotation (radians), per-axis scale.
    pub location: [f64; 3],
    pub rotation: [f64; 3],
    pub scale: [f64; 3],
    pub material: MaterialSpec,
    /// The disparity the planner aimed this object's centre at (content objects only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_disparity: Option<f64>,
}

impl ObjectSpec {
    /// This object's semantic class id ([`SEMANTIC_CLASSES`]).
    pub fn semantic_class(&self) -> u16 {
        let at = |name: &str| SEMANTIC_CLASSES.iter().position(|c| *c == name);
        let i = at(&self.source).unwrap_or_else(|| at("other").expect("`other` is a class"));
        i as u16 + 1
    }
}

/// Geometry in object space; every shape fits the unit sphere before `scale`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A square in the XY plane, side 2 (−1..1), facing +Z.
    Plane,
    /// Cube with half-size 1/√3 so its corners touch the unit sphere.
    Cube,
    UvSphere {
        segments: u32,
        rings: u32,
    },
    IcoSphere {
        subdivisions: u32,
    },
    /// Cylinder along Z, radius and half-height 1/√2.
    Cylinder {
        vertices: u32,
    },
    /// Cone along Z with the same bounds as the cylinder; `top_ratio` = top radius / bottom radius.
    Cone {
        vertices: u32,
        top_ratio: f64,
    },
    /// Torus in the XY plane; `minor_ratio` = tube radius / ring radius, outer radius 1.
    Torus {
        major_segments: u32,
        minor_segments: u32,
        minor_ratio: f64,
    },
    /// A subdivided square (−1/√2..1/√2), useful with the wireframe modifier as a grid of holes.
    Grid {
        x_segments: u32,
        y_segments: u32,
    },
    /// Blender's Suzanne, scaled into the unit sphere.
    Monkey,
    /// Explicit triangles (exactness tests, and callers that bring their own mesh).
    Mesh {
        vertices: Vec<[f64; 3]>,
        triangles: Vec<[u32; 3]>,
    },
    /// A mesh file. The worker loads the first candidate that imports, is not empty and has at
    /// most `max_triangles`, normalises it to the unit bounding sphere, and reports the others
    /// as skipped assets. Candidates are drawn by the planner, so the choice is deterministic.
    MeshFile {
        candidates: Vec<PathBuf>,
        max_triangles: u64,
    },
    /// Tubes along polylines (tree branches, net strands) and alpha-cut leaf quads.
    /// `strand_levels[i]` is strand i's branch level (0 = trunk); empty for nets.
    Skeleton {
        strands: Vec<Strand>,
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        strand_levels: Vec<u32>,
        sides: u32,
        leaves: Vec<Leaf>,
        leaf_material: Option<Box<MaterialSpec>>,
    },
}

impl Shape {
    /// A net of hexagonal tubes along `strands` (all of one level, no leaves).
    pub fn net(strands: Vec<Strand>) -> Self {
        Shape::Skeleton {
            strands,
            strand_levels: Vec::new(),
            sides: 6,
            leaves: Vec::new(),
            leaf_material: None,
        }
    }
}

/// A tube along a polyline, with a radius at every point (object space).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Strand {
    pub points: Vec<[f64; 3]>,
    pub radii: Vec<f64>,
}

/// A leaf: a quad centred at `center`, spanned by `u` (half-width vector) and `v` (half-length
/// vector), cut to an ellipse by a 0/1 alpha mask.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leaf {
    pub center: [f64; 3],
    pub u: [f64; 3],
    pub v: [f64; 3],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Modifier {
    /// Keeps only a lattice of the edges, `thickness` in object units (holes and open-work).
    Wireframe { thickness: f64 },
    /// Catmull–Clark subdivision.
    Subdivide { levels: u32 },
    /// Pushes vertices along normals by a noise texture.
    Displace {
        strength: f64,
        noise_scale: f64,
        offset: [f64; 3],
    },
    /// Cuts a cube or sphere (object space) out of the shape.
    BooleanCut {
        cutter: Cutter,
        location: [f64; 3],
        rotation: [f64; 3],
        scale: [f64; 3],
    },
    /// Lowers (or raises) the object along world Y until its lowest vertex, after its rotation
    /// and scale, lies at `y`: a mesh fits the unit sphere, so a flat one placed by its sphere
    /// would float above the floor. Applied to the shape before Blender's modifiers, so it comes
    /// only on objects without them.
    RestOnFloor { y: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cutter {
    Cube,
    Sphere,
}

/// The kind of surface, as the recipe's material weights name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialClass {
    /// Photo or procedural texture.
    Textured,
    /// One flat colour: no features to match.
    Textureless,
    /// Low-roughness dielectric with strong highlights.
    Glossy,
    /// Metallic = 1: mirror-like reflections.
    Metallic,
    /// Transmission = 1: refracting glass. Ground truth is its first surface.
    Glass,
}

impl MaterialClass {
    /// The `pass_index` a material of this class carries into Cycles' material-index pass,
    /// rendered with the depth pass: glass 1, metallic 2, others 0. A sample's pixels whose first
    /// surface has a non-zero index show glass or a mirror-like metal ([`MaterialSpec::pass_index`]).
    pub fn pass_index(self) -> u32 {
        match self {
            Self::Glass => 1,
            Self::Metallic => 2,
            Self::Textured | Self::Textureless | Self::Glossy => 0,
        }
    }
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

/// A Principled BSDF surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub class: MaterialClass,
    pub base: BaseColor,
    pub roughness: f64,
    pub metallic: f64,
    pub transmission: f64,
    pub ior: f64,
    /// Cycles' material pass index: [`MaterialClass::pass_index`] of `class` (absent, 0, in
    /// specs planned before it was written, which render as before).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub pass_index: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum BaseColor {
    Flat {
        color: [f64; 3],
    },
    /// A procedural Blender texture in object coordinates, blended between two colours.
    Procedural {
        pattern: Pattern,
        scale: f64,
        color_a: [f64; 3],
        color_b: [f64; 3],
        detail: f64,
    },
    /// A photo, box-projected in object coordinates (works without UVs); `scale` = repeats per
    /// object unit (large = strongly repetitive). `fallback` is used if Blender cannot load it.
    /// `texture_px`: use a copy downsampled to this longer side (the planner's mip level, so a
    /// strongly minified photo does not alias); `stretch`: per-axis factors on `scale` that keep
    /// texels square on a non-uniformly scaled object.
    Image {
        path: PathBuf,
        scale: f64,
        rotation: f64,
        fallback: [f64; 3],
        #[serde(default, skip_serializing_if = "Option::is_none")]
        texture_px: Option<u32>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        stretch: Option<[f64; 3]>,
    },
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
    Gradient,
}

impl Pattern {
    pub const ALL: [Pattern; 7] = [
        Pattern::Noise,
        Pattern::Voronoi,
        Pattern::Checker,
        Pattern::Wave,
        Pattern::Brick,
        Pattern::Magic,
        Pattern::Gradient,
    ];
}

impl MaterialSpec {
    /// A diffuse flat-colour surface.
    pub fn flat(color: [f64; 3], roughness: f64) -> Self {
        Self {
            class: MaterialClass::Textureless,
            base: BaseColor::Flat { color },
            roughness,
            metallic: 0.0,
            transmission: 0.0,
            ior: 1.45,
            pass_index: 0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightSpec {
    /// Omni light; `radius` softens shadows.
    Point {
        location: [f64; 3],
        color: [f64; 3],
        power_w: f64,
        radius: f64,
    },
    /// Cone light pointing along its local −Z, `spot_size` full angle (radians).
    Spot {
        location: [f64; 3],
        rotation: [f64; 3],
        color: [f64; 3],
        power_w: f64,
        radius: f64,
        spot_size: f64,
        blend: f64,
    },
    /// Square emitter of side `size` facing its local −Z.
    Area {
        location: [f64; 3],
        rotation: [f64; 3],
        color: [f64; 3],
        power_w: f64,
        size: f64,
    },
    /// Directional light along its local −Z.
    Sun {
        rotation: [f64; 3],
        color: [f64; 3],
        strength: f64,
    },
}

/// The JSON form of a [`SceneSpec`] as written: its fields plus the derived `cameras`; `render`
/// as a spec file has it ([`RenderSettings`]) or as the worker is sent it
/// ([`RenderSettings::resolved`]).
#[derive(Serialize)]
struct SceneSpecOut<'a, R> {
    format_version: u32,
    id: &'a str,
    category: &'a str,
    seed: u64,
    index: u64,
    rig: &'a StereoRig,
    cameras: StereoCameras,
    render: R,
    world: &'a WorldSpec,
    objects: &'a [ObjectSpec],
    lights: &'a [LightSpec],
}

/// The JSON form as read: `cameras` may be absent (version 2) and must match the rig if present.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneSpecIn {
    format_version: u32,
    id: String,
    category: String,
    seed: u64,
    index: u64,
    rig: StereoRig,
    #[serde(default)]
    cameras: Option<StereoCameras>,
    render: RenderSettings,
    world: WorldSpec,
    objects: Vec<ObjectSpec>,
    lights: Vec<LightSpec>,
}

impl SceneSpec {
    fn out<R>(&self, render: R) -> SceneSpecOut<'_, R> {
        SceneSpecOut {
            format_version: self.format_version,
            id: &self.id,
            category: &self.category,
            seed: self.seed,
            index: self.index,
            rig: &self.rig,
            cameras: self.rig.cameras(),
            render,
            world: &self.world,
            objects: &self.objects,
            lights: &self.lights,
        }
    }

    /// The spec as the worker is sent it: as written, but with every render key present
    /// ([`RenderSettings::resolved`]), so the defaults of keys a spec leaves out live in Rust.
    pub fn for_worker(&self) -> impl Serialize + '_ {
        self.out(self.render.resolved())
    }
}

impl Serialize for SceneSpec {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.out(&self.render).serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for SceneSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let s = SceneSpecIn::deserialize(deserializer)?;
        if s.format_version > SPEC_FORMAT_VERSION {
            return Err(serde::de::Error::custom(format!(
                "SceneSpec format_version {} is newer than this stereogen reads ({SPEC_FORMAT_VERSION})",
                s.format_version
            )));
        }
        if let Some(cameras) = &s.cameras
            && !cameras.agrees_with(&s.rig.cameras())
        {
            return Err(serde::de::Error::custom(
                "SceneSpec `cameras` disagree with its `rig` (they are derived from it: fix the rig, or drop `cameras`)",
            ));
        }
        Ok(SceneSpec {
            format_version: SPEC_FORMAT_VERSION,
            id: s.id,
            category: s.category,
            seed: s.seed,
            index: s.index,
            rig: s.rig,
            render: s.render,
            world: s.world,
            objects: s.objects,
            lights: s.lights,
        })
    }
}

impl SceneSpec {
    /// The camera facts the JSON carries (derived from the rig).
    pub fn cameras(&self) -> StereoCameras {
        self.rig.cameras()
    }

    /// What lies behind the floating objects, read from what was planned: a sky or an HDR
    /// environment is an `environment`, surfaces of a room a `room`, anything else the paper's `wall`.
    pub fn background_kind(&self) -> BackgroundKind {
        if self.world.sky.is_some() || self.world.hdri.is_some() {
            BackgroundKind::Environment
        } else if self.objects.iter().any(|o| o.source == "room") {
            BackgroundKind::Room
        } else {
            BackgroundKind::Wall
        }
    }

    /// Canonical JSON: the bytes that go to disk and to the worker. Field order is fixed by the
    /// struct definitions and floats print in shortest round-trip form, so equal specs give
    /// equal bytes.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a SceneSpec always serialises")
    }

    pub fn from_json(text: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(text)
    }

    /// Target disparities of the content objects (the object-level sample of the disparity law).
    pub fn target_disparities(&self) -> impl Iterator<Item = f64> + '_ {
        self.objects
            .iter()
            .filter(|o| o.role == ObjectRole::Content)
            .filter_map(|o| o.target_disparity)
    }
}

#[cfg(test)]
mod tests;
