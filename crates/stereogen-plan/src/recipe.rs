//! Recipes: TOML files that say what a dataset should look like. Every key is checked; an unknown
//! key or a value out of range is an error that names the key and what is allowed.
//!
//! The presets reproduce the CREStereo paper's four scene categories (`shapenet`, `tree`, `hole`,
//! `reflective`) and their mix (`crestereo`, the default).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

pub use super::dist::{CountRange, Dist};
use super::spec::{MaterialClass, PixelFilter};

/// Built-in presets: (name, TOML).
pub const PRESETS: &[(&str, &str)] = &[
    ("crestereo", include_str!("../recipes/crestereo.toml")),
    ("shapenet", include_str!("../recipes/shapenet.toml")),
    ("tree", include_str!("../recipes/tree.toml")),
    ("hole", include_str!("../recipes/hole.toml")),
    ("reflective", include_str!("../recipes/reflective.toml")),
];

/// The preset used when the user names none.
pub const DEFAULT_PRESET: &str = "crestereo";

#[derive(Debug, thiserror::Error)]
pub enum RecipeError {
    #[error("cannot read recipe {path}: {source} (built-in presets: crestereo, shapenet, tree, hole, reflective)")]
    Read { path: String, source: std::io::Error },
    #[error("recipe {source_name}: {message}{location}")]
    Parse { source_name: String, message: String, location: String },
    #[error("recipe {source_name}: key `{key}` is invalid: {allowed}")]
    Invalid { source_name: String, key: String, allowed: String },
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
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderRecipe {
    pub samples: u32,
    pub denoise: bool,
    pub max_bounces: u32,
    pub pixel_filter: PixelFilter,
    pub filter_width_px: f64,
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
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CategoryRecipe {
    pub name: String,
    pub weight: f64,
    pub objects: CountRange,
    pub shapes: BTreeMap<ShapeSource, f64>,
    pub materials: BTreeMap<MaterialClass, f64>,
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    (line, col)
}

fn folder_name_ok(name: &str) -> bool {
    !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

impl Recipe {
    pub fn builtin_default() -> Self {
        Self::preset(DEFAULT_PRESET).expect("the default preset exists")
    }

    /// A built-in preset by name.
    pub fn preset(name: &str) -> Option<Self> {
        PRESETS.iter().find(|(n, _)| *n == name).map(|(n, text)| {
            Self::from_toml_str(text, &format!("<preset {n}>")).unwrap_or_else(|e| panic!("built-in preset {n} is invalid: {e}"))
        })
    }

    /// A preset name or a path to a TOML file.
    pub fn load_or_preset(name_or_path: &str) -> Result<Self, RecipeError> {
        if !name_or_path.contains(['/', '.']) {
            if let Some(r) = Self::preset(name_or_path) {
                return Ok(r);
            }
        }
        Self::load(Path::new(name_or_path))
    }

    pub fn load(path: &Path) -> Result<Self, RecipeError> {
        let text = std::fs::read_to_string(path).map_err(|source| RecipeError::Read { path: path.display().to_string(), source })?;
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
        Sha256::digest(json.as_bytes()).iter().take(8).map(|b| format!("{b:02x}")).collect()
    }

    pub fn category(&self, name: &str) -> Option<&CategoryRecipe> {
        self.categories.iter().find(|c| c.name == name)
    }

    fn validate(&self, source_name: &str) -> Result<(), RecipeError> {
        let bad = |key: &str, allowed: String| RecipeError::Invalid { source_name: source_name.to_string(), key: key.to_string(), allowed };
        let dist = |key: &str, d: &Dist, lo: f64, hi: f64| d.validate(lo, hi).map_err(|m| bad(key, m));
        let count = |key: &str, c: &CountRange, lo: u32, hi: u32| c.validate(lo, hi).map_err(|m| bad(key, m));
        let prob = |key: &str, p: f64| if (0.0..=1.0).contains(&p) { Ok(()) } else { Err(bad(key, format!("need a probability in 0..=1, got {p}"))) };
        fn weights<K: std::fmt::Debug>(w: &BTreeMap<K, f64>) -> Result<(), String> {
            if w.values().any(|v| !(v.is_finite() && *v >= 0.0)) || w.values().sum::<f64>() <= 0.0 {
                return Err(format!("need weights >= 0 with a positive sum, got {w:?}"));
            }
            Ok(())
        }

        if !folder_name_ok(&self.name) {
            return Err(bad("name", format!("need letters, digits, '_' or '-', got {:?}", self.name)));
        }
        let c = &self.camera;
        if !(16..=16384).contains(&c.width) {
            return Err(bad("camera.width", format!("need 16..=16384, got {}", c.width)));
        }
        if !(16..=16384).contains(&c.height) {
            return Err(bad("camera.height", format!("need 16..=16384, got {}", c.height)));
        }
        dist("camera.focal_mm", &c.focal_mm, 1.0, 1000.0)?;
        if !(c.sensor_width_mm.is_finite() && (1.0..=100.0).contains(&c.sensor_width_mm)) {
            return Err(bad("camera.sensor_width_mm", format!("need 1..=100, got {}", c.sensor_width_mm)));
        }
        dist("camera.baseline_m", &c.baseline_m, 1e-4, 10.0)?;

        let r = &self.render;
        if !(1..=65536).contains(&r.samples) {
            return Err(bad("render.samples", format!("need 1..=65536, got {}", r.samples)));
        }
        if r.max_bounces > 128 {
            return Err(bad("render.max_bounces", format!("need 0..=128, got {}", r.max_bounces)));
        }
        if !(0.01..=10.0).contains(&r.filter_width_px) {
            return Err(bad("render.filter_width_px", format!("need 0.01..=10, got {}", r.filter_width_px)));
        }

        let p = &self.placement;
        // An object centre must fit in both views: its disparity must leave room in the width.
        dist("placement.disparity_px", &p.disparity_px, 0.01, f64::from(c.width) * 0.8)?;
        dist("placement.angular_size", &p.angular_size, 1e-3, 3.0)?;
        if !(0.0..0.4).contains(&p.margin) {
            return Err(bad("placement.margin", format!("need 0 <= margin < 0.4, got {}", p.margin)));
        }
        let law_min = p.disparity_px.support().0;
        dist("placement.background_disparity_px", &p.background_disparity_px, 1e-3, law_min * 0.999)
            .map_err(|_| bad("placement.background_disparity_px", format!("must lie in (0, {law_min}) — below the disparity law's minimum")))?;

        let l = &self.lights;
        count("lights.count", &l.count, 0, 64)?;
        weights(&l.kinds).map_err(|m| bad("lights.kinds", m))?;
        dist("lights.power_w", &l.power_w, 0.0, 1e8)?;
        dist("lights.sun_strength", &l.sun_strength, 0.0, 1e3)?;
        prob("lights.blackbody_fraction", l.blackbody_fraction)?;
        dist("lights.temperature_k", &l.temperature_k, 800.0, 40000.0)?;
        dist("lights.world_strength", &l.world_strength, 0.0, 100.0)?;

        if !(1..=100_000_000).contains(&self.sources.max_triangles) {
            return Err(bad("sources.max_triangles", format!("need 1..=100000000, got {}", self.sources.max_triangles)));
        }
        let pr = &self.primitives;
        dist("primitives.proportions", &pr.proportions, 0.05, 20.0)?;
        prob("primitives.subdivide_probability", pr.subdivide_probability)?;
        prob("primitives.displace_probability", pr.displace_probability)?;
        dist("primitives.displace_strength", &pr.displace_strength, 0.0, 1.0)?;
        prob("primitives.boolean_probability", pr.boolean_probability)?;

        let t = &self.trees;
        count("trees.levels", &t.levels, 1, 3)?;
        count("trees.branches", &t.branches, 1, 40)?;
        dist("trees.length_ratio", &t.length_ratio, 0.05, 1.5)?;
        dist("trees.down_angle_deg", &t.down_angle_deg, 0.0, 170.0)?;
        dist("trees.curve_deg", &t.curve_deg, -180.0, 180.0)?;
        dist("trees.trunk_radius", &t.trunk_radius, 1e-3, 0.3)?;
        count("trees.leaves_per_branch", &t.leaves_per_branch, 0, 64)?;
        dist("trees.leaf_size", &t.leaf_size, 1e-3, 0.5)?;

        let h = &self.holes;
        dist("holes.wire_thickness", &h.wire_thickness, 1e-3, 0.5)?;
        count("holes.net_cells", &h.net_cells, 1, 64)?;
        dist("holes.net_strand", &h.net_strand, 1e-3, 0.45)?;

        let m = &self.materials;
        dist("materials.texture_scale", &m.texture_scale, 1e-3, 1e4)?;
        dist("materials.roughness", &m.roughness, 0.0, 1.0)?;
        dist("materials.ior", &m.ior, 1.0, 3.0)?;
        weights(&m.background).map_err(|e| bad("materials.background", e))?;

        if self.categories.is_empty() {
            return Err(bad("categories", "need at least one [[categories]] table".into()));
        }
        let mut seen = std::collections::BTreeSet::new();
        for (i, cat) in self.categories.iter().enumerate() {
            let key = |k: &str| format!("categories[{i}].{k}");
            if !folder_name_ok(&cat.name) || !seen.insert(cat.name.clone()) {
                return Err(bad(&key("name"), format!("need a unique folder name, got {:?}", cat.name)));
            }
            if !(cat.weight.is_finite() && cat.weight >= 0.0) {
                return Err(bad(&key("weight"), format!("need >= 0, got {}", cat.weight)));
            }
            count(&key("objects"), &cat.objects, 0, 2000)?;
            weights(&cat.shapes).map_err(|m| bad(&key("shapes"), m))?;
            weights(&cat.materials).map_err(|m| bad(&key("materials"), m))?;
        }
        if self.categories.iter().map(|c| c.weight).sum::<f64>() <= 0.0 {
            return Err(bad("categories", "the category weights sum to 0".into()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_parses_and_round_trips() {
        for (name, _) in PRESETS {
            let r = Recipe::preset(name).unwrap();
            let back: Recipe = toml::from_str(&toml::to_string(&r).unwrap()).unwrap();
            assert_eq!(r, back, "{name}");
            assert_eq!(r.fingerprint(), back.fingerprint());
        }
        assert_eq!(Recipe::builtin_default().name, "crestereo");
        assert_eq!(Recipe::builtin_default().categories.len(), 4);
    }

    fn default_text() -> &'static str {
        PRESETS[0].1
    }

    #[test]
    fn unknown_key_is_named_with_its_line() {
        let text = default_text().replace("[render]", "[render]\nspp = 3");
        let err = Recipe::from_toml_str(&text, "x.toml").unwrap_err().to_string();
        assert!(err.contains("unknown field `spp`") && err.contains("line"), "{err}");
        assert!(!err.contains('\n'), "{err}");
    }

    #[test]
    fn missing_key_is_named() {
        let text = default_text().replace("samples = ", "# samples = ");
        let err = Recipe::from_toml_str(&text, "x.toml").unwrap_err().to_string();
        assert!(err.contains("missing field `samples`"), "{err}");
    }

    #[test]
    fn bad_distribution_is_named() {
        let text = default_text().replace("focal_mm = { dist = \"uniform\"", "focal_mm = { dist = \"cauchy\"");
        let err = Recipe::from_toml_str(&text, "x.toml").unwrap_err().to_string();
        assert!(err.contains("unknown variant `cauchy`"), "{err}");
    }

    #[test]
    fn out_of_range_values_name_key_and_bounds() {
        let err = Recipe::from_toml_str(&default_text().replace("width = 960", "width = 4"), "x.toml").unwrap_err().to_string();
        assert!(err.contains("camera.width") && err.contains("16..=16384"), "{err}");
        let err = Recipe::from_toml_str(&default_text().replace("boolean_probability = 0.25", "boolean_probability = 1.5"), "x.toml").unwrap_err().to_string();
        assert!(err.contains("primitives.boolean_probability"), "{err}");
    }
}
