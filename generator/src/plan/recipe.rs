//! Recipes: TOML files that say what a dataset should look like. Every key is checked; an unknown
//! key or a value out of range is an error that names the key and what is allowed.

use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::spec::PixelFilter;

/// The recipe used when the user gives none: small, fast, textured primitives in front of a wall.
pub const DEFAULT_RECIPE_TOML: &str = include_str!("../../recipes/default.toml");

#[derive(Debug, thiserror::Error)]
pub enum RecipeError {
    #[error("cannot read recipe {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("recipe {source_name}: {message}{location}")]
    Parse { source_name: String, message: String, location: String },
    #[error("recipe {source_name}: key `{key}` = {value} is invalid: {allowed}")]
    Invalid { source_name: String, key: String, value: String, allowed: String },
}

/// A closed interval `[min, max]`, written as a two-element array or a single number.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "RangeRepr", into = "[f64; 2]")]
pub struct Range {
    pub min: f64,
    pub max: f64,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum RangeRepr {
    Fixed(f64),
    Pair([f64; 2]),
}

impl From<RangeRepr> for Range {
    fn from(r: RangeRepr) -> Self {
        match r {
            RangeRepr::Fixed(v) => Range { min: v, max: v },
            RangeRepr::Pair([min, max]) => Range { min, max },
        }
    }
}

impl From<Range> for [f64; 2] {
    fn from(r: Range) -> Self {
        [r.min, r.max]
    }
}

/// An integer interval `[min, max]`, written as a two-element array or a single number.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "CountRepr", into = "[u32; 2]")]
pub struct CountRange {
    pub min: u32,
    pub max: u32,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum CountRepr {
    Fixed(u32),
    Pair([u32; 2]),
}

impl From<CountRepr> for CountRange {
    fn from(r: CountRepr) -> Self {
        match r {
            CountRepr::Fixed(v) => CountRange { min: v, max: v },
            CountRepr::Pair([min, max]) => CountRange { min, max },
        }
    }
}

impl From<CountRange> for [u32; 2] {
    fn from(r: CountRange) -> Self {
        [r.min, r.max]
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// Category name: the sub-folder the samples go to.
    pub name: String,
    pub camera: CameraRecipe,
    pub render: RenderRecipe,
    pub objects: ObjectsRecipe,
    pub background: BackgroundRecipe,
    pub lights: LightsRecipe,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraRecipe {
    pub width: u32,
    pub height: u32,
    /// Focal length drawn uniformly per scene (mm).
    pub focal_mm: Range,
    pub sensor_width_mm: f64,
    /// Baseline drawn uniformly per scene (m).
    pub baseline_m: Range,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderRecipe {
    pub samples: u32,
    pub denoise: bool,
    pub max_bounces: u32,
    /// Anti-aliasing filter of the colour images.
    #[serde(default = "default_filter")]
    pub pixel_filter: PixelFilter,
    #[serde(default = "default_filter_width")]
    pub filter_width_px: f64,
}

fn default_filter() -> PixelFilter {
    PixelFilter::BlackmanHarris
}

fn default_filter_width() -> f64 {
    1.5
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectsRecipe {
    pub count: CountRange,
    /// Target disparity of each object centre, drawn uniformly (px).
    pub disparity_px: Range,
    /// Object diameter as a fraction of the image width; world size then grows with depth.
    pub angular_size: Range,
    /// Which primitives to draw from, uniformly.
    pub shapes: Vec<PrimitiveKind>,
    /// Probability that an object gets a procedural texture rather than a flat colour.
    pub textured_fraction: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PrimitiveKind {
    Cube,
    UvSphere,
    IcoSphere,
    Cylinder,
    Torus,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackgroundRecipe {
    /// Disparity of the textured back wall (px); must lie below every object's disparity.
    pub disparity_px: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightsRecipe {
    pub count: CountRange,
    /// Point-light power, drawn log-uniformly (W).
    pub power_w: Range,
    /// Uniform world light strength.
    pub world_strength: Range,
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    (line, col)
}

impl Recipe {
    pub fn builtin_default() -> Self {
        Self::from_toml_str(DEFAULT_RECIPE_TOML, "<built-in default>").expect("the built-in recipe is valid")
    }

    pub fn load(path: &Path) -> Result<Self, RecipeError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| RecipeError::Read { path: path.display().to_string(), source })?;
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
        let digest = Sha256::digest(json.as_bytes());
        digest.iter().take(8).map(|b| format!("{b:02x}")).collect()
    }

    fn validate(&self, source_name: &str) -> Result<(), RecipeError> {
        let bad = |key: &str, value: String, allowed: &str| RecipeError::Invalid {
            source_name: source_name.to_string(),
            key: key.to_string(),
            value,
            allowed: allowed.to_string(),
        };
        let check_range = |key: &str, r: Range, lo: f64, hi: f64| -> Result<(), RecipeError> {
            if !(r.min.is_finite() && r.max.is_finite() && lo <= r.min && r.min <= r.max && r.max <= hi) {
                return Err(bad(key, format!("[{}, {}]", r.min, r.max), &format!("need {lo} <= min <= max <= {hi}")));
            }
            Ok(())
        };
        let check_count = |key: &str, r: CountRange, lo: u32, hi: u32| -> Result<(), RecipeError> {
            if !(lo <= r.min && r.min <= r.max && r.max <= hi) {
                return Err(bad(key, format!("[{}, {}]", r.min, r.max), &format!("need {lo} <= min <= max <= {hi}")));
            }
            Ok(())
        };
        let name_ok = !self.name.is_empty()
            && self.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !name_ok {
            return Err(bad("name", format!("{:?}", self.name), "need a non-empty folder name of letters, digits, '_' or '-'"));
        }
        let c = &self.camera;
        if !(16..=16384).contains(&c.width) {
            return Err(bad("camera.width", c.width.to_string(), "need 16..=16384"));
        }
        if !(16..=16384).contains(&c.height) {
            return Err(bad("camera.height", c.height.to_string(), "need 16..=16384"));
        }
        check_range("camera.focal_mm", c.focal_mm, 1.0, 1000.0)?;
        if !(c.sensor_width_mm.is_finite() && (1.0..=100.0).contains(&c.sensor_width_mm)) {
            return Err(bad("camera.sensor_width_mm", c.sensor_width_mm.to_string(), "need 1..=100"));
        }
        check_range("camera.baseline_m", c.baseline_m, 1e-4, 10.0)?;
        if !(1..=65536).contains(&self.render.samples) {
            return Err(bad("render.samples", self.render.samples.to_string(), "need 1..=65536"));
        }
        if !(0.01..=10.0).contains(&self.render.filter_width_px) {
            return Err(bad("render.filter_width_px", self.render.filter_width_px.to_string(), "need 0.01..=10"));
        }
        if self.render.max_bounces > 128 {
            return Err(bad("render.max_bounces", self.render.max_bounces.to_string(), "need 0..=128"));
        }
        let o = &self.objects;
        check_count("objects.count", o.count, 0, 1000)?;
        // An object must stay visible in both views: its disparity must leave room in the width.
        let max_disp = f64::from(c.width) / 2.0;
        check_range("objects.disparity_px", o.disparity_px, 0.01, max_disp)?;
        check_range("objects.angular_size", o.angular_size, 1e-3, 2.0)?;
        if o.shapes.is_empty() {
            return Err(bad("objects.shapes", "[]".into(), "need at least one of cube, uv_sphere, ico_sphere, cylinder, torus"));
        }
        if !(0.0..=1.0).contains(&o.textured_fraction) {
            return Err(bad("objects.textured_fraction", o.textured_fraction.to_string(), "need 0..=1"));
        }
        let bg = self.background.disparity_px;
        if !(bg.is_finite() && bg > 0.0 && bg < o.disparity_px.min) {
            return Err(bad("background.disparity_px", bg.to_string(), &format!("need 0 < value < objects.disparity_px min ({})", o.disparity_px.min)));
        }
        check_count("lights.count", self.lights.count, 0, 64)?;
        check_range("lights.power_w", self.lights.power_w, 1e-3, 1e7)?;
        check_range("lights.world_strength", self.lights.world_strength, 0.0, 100.0)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_default_parses_and_round_trips() {
        let r = Recipe::builtin_default();
        let back: Recipe = toml::from_str(&toml::to_string(&r).unwrap()).unwrap();
        assert_eq!(r, back);
        assert_eq!(r.fingerprint(), back.fingerprint());
    }

    #[test]
    fn unknown_key_is_named_with_its_line() {
        let text = DEFAULT_RECIPE_TOML.replace("[render]", "[render]\nspp = 3");
        let err = Recipe::from_toml_str(&text, "x.toml").unwrap_err().to_string();
        assert!(err.contains("unknown field `spp`") && err.contains("line"), "{err}");
        assert!(!err.contains('\n'), "{err}");
    }

    #[test]
    fn missing_key_is_named() {
        let text = DEFAULT_RECIPE_TOML.replace("samples = ", "# samples = ");
        let err = Recipe::from_toml_str(&text, "x.toml").unwrap_err().to_string();
        assert!(err.contains("missing field `samples`"), "{err}");
    }

    #[test]
    fn out_of_range_value_names_key_and_bounds() {
        let text = DEFAULT_RECIPE_TOML.replace("width = 320", "width = 4");
        let err = Recipe::from_toml_str(&text, "x.toml").unwrap_err().to_string();
        assert!(err.contains("camera.width") && err.contains("16..=16384"), "{err}");
    }
}
