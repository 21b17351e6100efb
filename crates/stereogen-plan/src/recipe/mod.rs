//! Recipes: TOML files that say what a dataset should look like. Every key is checked; an unknown
//! key or a value out of range is an error that names the key and what is allowed.
//!
//! The presets reproduce the CREStereo paper's four scene categories (`shapenet`, `tree`, `hole`,
//! `reflective`) and their mix (`crestereo`, the default).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

pub use super::dist::{CountRange, Dist, UniformRange};
pub use super::render::{RenderOverride, RenderRecipe};
use super::spec::MaterialClass;

mod validate;

/// Declares recipe keys that were added after the first recipes were written. An absent key takes
/// its default (the number the planner used before it was a key), and a value equal to its
/// default is not serialised: recipes that do not set these keys keep their fingerprint, so
/// datasets made before still resume.
macro_rules! added_keys {
    ($($name:ident: $t:ty = $value:expr;)*) => {
        mod default {
            use super::*;
            $(pub fn $name() -> $t { $value })*
        }
        mod is_default {
            use super::*;
            $(pub fn $name(v: &$t) -> bool { *v == super::default::$name() })*
        }
    };
}

added_keys! {
    clip_start_factor: f64 = 0.01;
    clip_end_factor: f64 = 2.0;
    background_oversize: f64 = 1.15;
    mesh_candidates: u32 = 3;
    light_near_factor: f64 = 0.5;
    light_far_factor: f64 = 0.9;
    light_image_position: UniformRange = UniformRange::new(-0.2, 1.2);
    light_color_channel: UniformRange = UniformRange::new(0.2, 1.0);
    light_radius_factor: f64 = 0.02;
    light_area_size_factor: UniformRange = UniformRange::new(0.05, 0.3);
    light_spot_size_rad: UniformRange = UniformRange::new(0.4, 1.6);
    light_spot_blend: UniformRange = UniformRange::new(0.05, 0.5);
    light_tilt_rad: UniformRange = UniformRange::new(-0.6, 0.6);
    world_grey: UniformRange = UniformRange::new(0.6, 1.0);
    world_green_ratio: UniformRange = UniformRange::new(0.85, 1.0);
    world_blue_ratio: UniformRange = UniformRange::new(0.8, 1.0);
    leaf_rgb: [UniformRange; 3] = [UniformRange::new(0.05, 0.35), UniformRange::new(0.25, 0.7), UniformRange::new(0.02, 0.2)];
    leaf_roughness: f64 = 0.6;
    tree_lean_rad: UniformRange = UniformRange::new(-0.15, 0.15);
    background_texture_scale: [f64; 2] = [0.5, 6.0];
    procedural_detail: UniformRange = UniformRange::new(0.0, 8.0);
    glossy_textured_probability: f64 = 0.5;
    glossy_roughness: UniformRange = UniformRange::new(0.0, 0.12);
    metallic_roughness: UniformRange = UniformRange::new(0.0, 0.35);
    metallic_tint: UniformRange = UniformRange::new(0.55, 1.0);
    glass_roughness: UniformRange = UniformRange::new(0.0, 0.08);
    glass_tint: UniformRange = UniformRange::new(0.75, 1.0);
    builtin_pack: bool = false;
    exclude_licences: Vec<String> = Vec::new();
    pack_mesh_share: f64 = 0.5;
    procedural_share: f64 = 0.0;
    photo_texel_px: Option<[f64; 2]> = None;
}

/// Built-in presets: (name, TOML).
pub const PRESETS: &[(&str, &str)] = &[
    ("crestereo", include_str!("../../recipes/crestereo.toml")),
    ("shapenet", include_str!("../../recipes/shapenet.toml")),
    ("tree", include_str!("../../recipes/tree.toml")),
    ("hole", include_str!("../../recipes/hole.toml")),
    ("reflective", include_str!("../../recipes/reflective.toml")),
    ("wmgstereo", include_str!("../../recipes/wmgstereo.toml")),
];

/// The preset used when the user names none.
pub const DEFAULT_PRESET: &str = "crestereo";

/// The largest recipe file read: the limits policy's largest document
/// (`stereo_io::limits::MAX_DOCUMENT_BYTES`, which this crate does not link; a test in the
/// generator holds the two equal). A real recipe is a few kilobytes.
pub const MAX_RECIPE_BYTES: u64 = 64 << 20;

#[derive(Debug, thiserror::Error)]
pub enum RecipeError {
    #[error(
        "cannot read recipe {path}: {source} (built-in presets: crestereo, shapenet, tree, hole, reflective, wmgstereo)"
    )]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("recipe {source_name}: {message}{location}")]
    Parse {
        source_name: String,
        message: String,
        location: String,
    },
    #[error("recipe {source_name}: key `{key}` is invalid: {allowed}")]
    Invalid {
        source_name: String,
        key: String,
        allowed: String,
    },
}

/// Where shapes come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeSource {
    /// Procedurally varied Blender primitives (always available).
    Primitive,
    /// ShapeNetCore v1/v2 models from `sources.shapenet` (primitives stand in when unset).
    Shapenet,
    /// Any mesh folder from `sources.meshes` (primitives stand in when unset).
    Meshes,
    /// Weber–Penn style trees with leaves.
    Tree,
    /// Primitives through the wireframe modifier: holes and open-work.
    Wireframe,
    /// Nets, lattices and fences of thin tubes.
    Net,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    pub name: String,
    pub camera: CameraRecipe,
    pub render: RenderRecipe,
    pub placement: PlacementRecipe,
    pub lights: LightsRecipe,
    pub sources: SourcesRecipe,
    pub primitives: PrimitiveRecipe,
    pub trees: TreeRecipe,
    pub holes: HoleRecipe,
    pub materials: MaterialRecipe,
    /// Scene categories; each scene draws one by weight.
    pub categories: Vec<CategoryRecipe>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraRecipe {
    pub width: u32,
    pub height: u32,
    pub focal_mm: Dist,
    pub sensor_width_mm: f64,
    pub baseline_m: Dist,
    /// Near clipping plane as a fraction of the nearest depth the disparity law allows.
    #[serde(
        default = "default::clip_start_factor",
        skip_serializing_if = "is_default::clip_start_factor"
    )]
    pub clip_start_factor: f64,
    /// Far clipping plane as a multiple of the back wall's depth.
    #[serde(
        default = "default::clip_end_factor",
        skip_serializing_if = "is_default::clip_end_factor"
    )]
    pub clip_end_factor: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlacementRecipe {
    /// The disparity law: each content object's centre gets a disparity drawn from it (px).
    pub disparity_px: Dist,
    /// Object diameter as a fraction of the image width; world size then grows with depth.
    pub angular_size: Dist,
    /// Fraction of the image kept free at each border when placing object centres.
    pub margin: f64,
    /// Disparity of the textured back wall (px); must stay below the law's minimum.
    pub background_disparity_px: Dist,
    /// Size of the back wall relative to the region both views see at its depth.
    #[serde(
        default = "default::background_oversize",
        skip_serializing_if = "is_default::background_oversize"
    )]
    pub background_oversize: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightsRecipe {
    pub count: CountRange,
    /// Relative weights of light kinds.
    pub kinds: BTreeMap<LightKind, f64>,
    /// Power of point/spot/area lights at 1 m scene scale (W); scaled by depth² in the scene.
    pub power_w: Dist,
    /// Sun strength (W/m²).
    pub sun_strength: Dist,
    /// Probability that a light's colour is a blackbody temperature rather than a random RGB.
    pub blackbody_fraction: f64,
    pub temperature_k: Dist,
    pub world_strength: Dist,
    /// Lights sit at depths from `near_factor` × the nearest depth the law allows ...
    #[serde(
        default = "default::light_near_factor",
        skip_serializing_if = "is_default::light_near_factor"
    )]
    pub near_factor: f64,
    /// ... to `far_factor` × the back wall's depth.
    #[serde(
        default = "default::light_far_factor",
        skip_serializing_if = "is_default::light_far_factor"
    )]
    pub far_factor: f64,
    /// Where a light sits across the view, as a fraction of the image width and height
    /// (outside 0..1: beside the view, lighting it from the side).
    #[serde(
        default = "default::light_image_position",
        skip_serializing_if = "is_default::light_image_position"
    )]
    pub image_position: UniformRange,
    /// Each channel of a light colour that is not a blackbody.
    #[serde(
        default = "default::light_color_channel",
        skip_serializing_if = "is_default::light_color_channel"
    )]
    pub color_channel: UniformRange,
    /// Radius of point and spot lights (soft shadows) per metre of depth.
    #[serde(
        default = "default::light_radius_factor",
        skip_serializing_if = "is_default::light_radius_factor"
    )]
    pub radius_factor: f64,
    /// Side of area lights per metre of depth.
    #[serde(
        default = "default::light_area_size_factor",
        skip_serializing_if = "is_default::light_area_size_factor"
    )]
    pub area_size_factor: UniformRange,
    /// Full cone angle of spot lights (radians).
    #[serde(
        default = "default::light_spot_size_rad",
        skip_serializing_if = "is_default::light_spot_size_rad"
    )]
    pub spot_size_rad: UniformRange,
    #[serde(
        default = "default::light_spot_blend",
        skip_serializing_if = "is_default::light_spot_blend"
    )]
    pub spot_blend: UniformRange,
    /// Tilt of directed lights away from the view direction, about X and Y (radians).
    #[serde(
        default = "default::light_tilt_rad",
        skip_serializing_if = "is_default::light_tilt_rad"
    )]
    pub tilt_rad: UniformRange,
    /// World colour: grey level, then green and blue as fractions of it.
    #[serde(
        default = "default::world_grey",
        skip_serializing_if = "is_default::world_grey"
    )]
    pub world_grey: UniformRange,
    #[serde(
        default = "default::world_green_ratio",
        skip_serializing_if = "is_default::world_green_ratio"
    )]
    pub world_green_ratio: UniformRange,
    #[serde(
        default = "default::world_blue_ratio",
        skip_serializing_if = "is_default::world_blue_ratio"
    )]
    pub world_blue_ratio: UniformRange,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LightKind {
    Point,
    Spot,
    Area,
    Sun,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SourcesRecipe {
    /// ShapeNetCore root (v1 `<synset>/<model>/model.obj` or v2 `.../models/model_normalized.obj`).
    #[serde(default)]
    pub shapenet: Option<PathBuf>,
    /// Only these synset ids (empty: all).
    #[serde(default)]
    pub shapenet_synsets: Vec<String>,
    /// A folder of meshes (OBJ, GLB/GLTF, PLY, STL, OFF).
    #[serde(default)]
    pub meshes: Option<PathBuf>,
    /// A folder of photos used as textures; procedural textures when unset.
    #[serde(default)]
    pub textures: Option<PathBuf>,
    /// Meshes with more triangles are skipped.
    pub max_triangles: u64,
    /// Mesh files drawn per object: the worker falls back along them when one fails to load.
    #[serde(
        default = "default::mesh_candidates",
        skip_serializing_if = "is_default::mesh_candidates"
    )]
    pub mesh_candidates: u32,
    /// Use the built-in content pack (real photos and meshes installed by `stereogen setup` from
    /// PyPI wheels): its photos texture surfaces when `textures` is unset, its meshes stand in for
    /// `shapenet`/`meshes` when those are unset. Off: procedural textures and primitives only.
    #[serde(
        default = "default::builtin_pack",
        skip_serializing_if = "is_default::builtin_pack"
    )]
    pub builtin_pack: bool,
    /// Licences of the built-in pack to leave out, as `stereogen assets list` names them
    /// (e.g. `["CC-BY-4.0"]`).
    #[serde(
        default = "default::exclude_licences",
        skip_serializing_if = "is_default::exclude_licences"
    )]
    pub exclude_licences: Vec<String>,
    /// Share of `shapenet`/`meshes` draws that the pack's meshes serve when no folder is given;
    /// the rest are varied primitives.
    #[serde(
        default = "default::pack_mesh_share",
        skip_serializing_if = "is_default::pack_mesh_share"
    )]
    pub pack_mesh_share: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrimitiveRecipe {
    /// Per-axis stretch factor range (random proportions).
    pub proportions: Dist,
    pub subdivide_probability: f64,
    pub displace_probability: f64,
    /// Displacement strength relative to the unit size.
    pub displace_strength: Dist,
    pub boolean_probability: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TreeRecipe {
    /// Recursive branch levels below the trunk (1..=3).
    pub levels: CountRange,
    /// Child branches per parent branch at level 1; deeper levels use 60% of it.
    pub branches: CountRange,
    /// Child length relative to its parent.
    pub length_ratio: Dist,
    /// Angle between a child and its parent (degrees).
    pub down_angle_deg: Dist,
    /// Accumulated bend along a branch (degrees).
    pub curve_deg: Dist,
    /// Trunk radius relative to tree height.
    pub trunk_radius: Dist,
    /// Leaves per last-level branch.
    pub leaves_per_branch: CountRange,
    /// Leaf length relative to tree height.
    pub leaf_size: Dist,
    /// Leaf colour, per channel (red, green, blue).
    #[serde(
        default = "default::leaf_rgb",
        skip_serializing_if = "is_default::leaf_rgb"
    )]
    pub leaf_rgb: [UniformRange; 3],
    #[serde(
        default = "default::leaf_roughness",
        skip_serializing_if = "is_default::leaf_roughness"
    )]
    pub leaf_roughness: f64,
    /// Lean of a tree from upright, about X and Z (radians).
    #[serde(
        default = "default::tree_lean_rad",
        skip_serializing_if = "is_default::tree_lean_rad"
    )]
    pub lean_rad: UniformRange,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HoleRecipe {
    /// Wireframe strand thickness relative to the unit size.
    pub wire_thickness: Dist,
    /// Net cells per side.
    pub net_cells: CountRange,
    /// Net strand radius relative to the cell size.
    pub net_strand: Dist,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialRecipe {
    /// Texture repeats per object unit; high values give strongly repetitive patterns.
    pub texture_scale: Dist,
    pub roughness: Dist,
    /// Index of refraction of glass.
    pub ior: Dist,
    /// Material weights of the back wall.
    pub background: BTreeMap<MaterialClass, f64>,
    /// The back wall's `texture_scale` is clamped to [min, max]: it is large, and many repeats
    /// would turn its texture into noise.
    #[serde(
        default = "default::background_texture_scale",
        skip_serializing_if = "is_default::background_texture_scale"
    )]
    pub background_texture_scale: [f64; 2],
    /// Detail of procedural textures (Blender's noise detail).
    #[serde(
        default = "default::procedural_detail",
        skip_serializing_if = "is_default::procedural_detail"
    )]
    pub procedural_detail: UniformRange,
    /// Probability that a glossy surface is textured rather than flat.
    #[serde(
        default = "default::glossy_textured_probability",
        skip_serializing_if = "is_default::glossy_textured_probability"
    )]
    pub glossy_textured_probability: f64,
    #[serde(
        default = "default::glossy_roughness",
        skip_serializing_if = "is_default::glossy_roughness"
    )]
    pub glossy_roughness: UniformRange,
    #[serde(
        default = "default::metallic_roughness",
        skip_serializing_if = "is_default::metallic_roughness"
    )]
    pub metallic_roughness: UniformRange,
    /// Each channel of a metal's tint.
    #[serde(
        default = "default::metallic_tint",
        skip_serializing_if = "is_default::metallic_tint"
    )]
    pub metallic_tint: UniformRange,
    #[serde(
        default = "default::glass_roughness",
        skip_serializing_if = "is_default::glass_roughness"
    )]
    pub glass_roughness: UniformRange,
    /// Each channel of a glass's tint.
    #[serde(
        default = "default::glass_tint",
        skip_serializing_if = "is_default::glass_tint"
    )]
    pub glass_tint: UniformRange,
    /// Share of textured surfaces that keep a procedural texture when photos are available.
    #[serde(
        default = "default::procedural_share",
        skip_serializing_if = "is_default::procedural_share"
    )]
    pub procedural_share: f64,
    /// Screen pixels per photo pixel allowed, [min, max]: above max a photo is tiled more often
    /// (no blurry, stretched photos), below min the worker uses a downsampled copy (no moiré).
    /// Unset: photos keep the drawn repeats at full resolution.
    #[serde(
        default = "default::photo_texel_px",
        skip_serializing_if = "is_default::photo_texel_px"
    )]
    pub photo_texel_px: Option<[f64; 2]>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CategoryRecipe {
    pub name: String,
    pub weight: f64,
    pub objects: CountRange,
    pub shapes: BTreeMap<ShapeSource, f64>,
    pub materials: BTreeMap<MaterialClass, f64>,
    /// This category's own render keys (`render = { samples = 24 }`): what the scenes of one
    /// category need differs (the render study's per-category picks); absent: `[render]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderOverride>,
    /// What fills the view behind the objects, by weight (`background = { wall = 0.2, room =
    /// 0.7, environment = 0.1 }`); absent: the wall alone, as the paper's scenes.
    #[serde(default = "wall_only", skip_serializing_if = "is_wall_only")]
    pub background: BTreeMap<crate::BackgroundKind, f64>,
}

fn wall_only() -> BTreeMap<crate::BackgroundKind, f64> {
    BTreeMap::from([(crate::BackgroundKind::Wall, 1.0)])
}

fn is_wall_only(weights: &BTreeMap<crate::BackgroundKind, f64>) -> bool {
    *weights == wall_only()
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    (line, col)
}

impl Recipe {
    /// The render settings of a category's scenes: `[render]` with the category's own keys.
    pub fn render_for(&self, category: &CategoryRecipe) -> RenderRecipe {
        match &category.render {
            Some(o) => o.apply(&self.render),
            None => self.render.clone(),
        }
    }

    pub fn builtin_default() -> Self {
        Self::preset(DEFAULT_PRESET).expect("the default preset exists")
    }

    /// A built-in preset by name.
    pub fn preset(name: &str) -> Option<Self> {
        PRESETS.iter().find(|(n, _)| *n == name).map(|(n, text)| {
            Self::from_toml_str(text, &format!("<preset {n}>"))
                .unwrap_or_else(|e| panic!("built-in preset {n} is invalid: {e}"))
        })
    }

    /// A preset name or a path to a TOML file.
    pub fn load_or_preset(name_or_path: &str) -> Result<Self, RecipeError> {
        if !name_or_path.contains(['/', '.'])
            && let Some(r) = Self::preset(name_or_path)
        {
            return Ok(r);
        }
        Self::load(Path::new(name_or_path))
    }

    /// Reads a recipe file of at most [`MAX_RECIPE_BYTES`], refusing a larger one before
    /// reading it.
    pub fn load(path: &Path) -> Result<Self, RecipeError> {
        use std::io::Read;
        let read_err = |source| RecipeError::Read {
            path: path.display().to_string(),
            source,
        };
        let file = std::fs::File::open(path).map_err(read_err)?;
        let meta = file.metadata().map_err(read_err)?;
        if !meta.is_file() || meta.len() > MAX_RECIPE_BYTES {
            return Err(read_err(std::io::Error::other(format!(
                "not a regular file of at most {} MiB",
                MAX_RECIPE_BYTES >> 20
            ))));
        }
        let mut text = String::new();
        file.take(MAX_RECIPE_BYTES)
            .read_to_string(&mut text)
            .map_err(read_err)?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    pub fn from_toml_str(text: &str, source_name: &str) -> Result<Self, RecipeError> {
        let recipe: Recipe = toml::from_str(text).map_err(|e| {
            let location = e.span().map_or(String::new(), |s| {
                let (l, c) = line_col(text, s.start);
                format!(" (line {l}, column {c})")
            });
            RecipeError::Parse {
                source_name: source_name.to_string(),
                // toml's message can span lines; the user gets one.
                message: e.message().split_whitespace().collect::<Vec<_>>().join(" "),
                location,
            }
        })?;
        recipe.validate(source_name)?;
        Ok(recipe)
    }

    /// A digest of the resolved recipe: datasets remember it so a resumed run cannot mix recipes.
    pub fn fingerprint(&self) -> String {
        let json = serde_json::to_string(self).expect("a Recipe always serialises");
        Sha256::digest(json.as_bytes())
            .iter()
            .take(8)
            .map(|b| format!("{b:02x}"))
            .collect()
    }

    pub fn category(&self, name: &str) -> Option<&CategoryRecipe> {
        self.categories.iter().find(|c| c.name == name)
    }
}

#[cfg(test)]
mod tests;
