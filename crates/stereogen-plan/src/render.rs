//! Render settings, one type from recipe to spec. [`RenderRecipe`] is what a recipe's `[render]`
//! (and a category's `render = { .. }`, [`RenderOverride`]) says; a scene's [`RenderSettings`]
//! are its category's [`RenderRecipe`] as it is, plus what the planner draws or derives per
//! scene (the Cycles seeds, the clipping range).
//!
//! Keys added after the first recipes and specs were written have defaults (what Cycles did
//! before they were settable), and a value equal to its default is not written: recipes keep
//! their fingerprint and specs their bytes, so datasets made before resume and re-render
//! unchanged. The worker is sent [`RenderSettings::resolved`] instead, every key with its value,
//! so these defaults live here and nowhere in `blender_scripts/`.

use serde::de::Error as _;
use serde::ser::{Error as _, SerializeStruct};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::{Map, Value};

/// Declares the render keys a file may leave out: their default, the check that skips writing
/// them at it, and [`defaults`], the table [`RenderSettings::resolved`] fills a spec in from.
macro_rules! optional_keys {
    ($($name:ident: $t:ty = $value:expr;)*) => {
        mod default {
            use super::*;
            $(pub fn $name() -> $t { $value })*
        }
        mod is_default {
            use super::*;
            $(pub fn $name(v: &$t) -> bool { *v == super::default::$name() })*
        }
        /// Every key a recipe or spec may leave out, with the value it then has.
        fn defaults() -> Map<String, Value> {
            let mut m = Map::new();
            $(m.insert(
                stringify!($name).to_string(),
                serde_json::to_value(default::$name()).expect("a default serialises"),
            );)*
            m
        }
    };
}

optional_keys! {
    adaptive_threshold: Option<f64> = None;
    adaptive_min_samples: u32 = 0;
    denoise_prefilter: DenoisePrefilter = DenoisePrefilter::Accurate;
    denoise_passes: DenoisePasses = DenoisePasses::AlbedoNormal;
    denoise_quality: DenoiseQuality = DenoiseQuality::High;
    light_tree: bool = true;
    outputs: Vec<OutputMap> = Vec::new();
}

/// A per-pixel map a recipe asks for beside the colour images and disparity (`[render] outputs`).
/// All come from the depth passes' first surface; none is written unless asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputMap {
    /// Metric depth along the optical axis.
    Depth,
    /// Camera-space unit surface normals.
    Normals,
    /// Instance ids (each object of the spec its own).
    Instance,
    /// Semantic class ids ([`crate::SEMANTIC_CLASSES`]).
    Semantic,
}

impl OutputMap {
    pub const ALL: [OutputMap; 4] = [Self::Depth, Self::Normals, Self::Instance, Self::Semantic];

    /// The name a recipe writes (and a dataset's files carry).
    pub fn name(self) -> &'static str {
        match self {
            Self::Depth => "depth",
            Self::Normals => "normals",
            Self::Instance => "instance",
            Self::Semantic => "semantic",
        }
    }
}

/// How OpenImageDenoise cleans its guiding passes before use.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DenoisePrefilter {
    #[default]
    Accurate,
    Fast,
    None,
}

/// The passes that guide the denoiser besides the noisy colour.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DenoisePasses {
    Rgb,
    Albedo,
    #[default]
    AlbedoNormal,
}

/// OpenImageDenoise's quality mode.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DenoiseQuality {
    #[default]
    High,
    Balanced,
    Fast,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelFilter {
    BlackmanHarris,
    Gaussian,
    Box,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderRecipe {
    pub samples: u32,
    pub denoise: bool,
    pub max_bounces: u32,
    pub pixel_filter: PixelFilter,
    pub filter_width_px: f64,
    /// Adaptive sampling's noise threshold; absent: adaptive sampling off.
    #[serde(
        default = "default::adaptive_threshold",
        skip_serializing_if = "is_default::adaptive_threshold"
    )]
    pub adaptive_threshold: Option<f64>,
    /// Adaptive sampling's minimum samples per pixel (0: Cycles' automatic choice).
    #[serde(
        default = "default::adaptive_min_samples",
        skip_serializing_if = "is_default::adaptive_min_samples"
    )]
    pub adaptive_min_samples: u32,
    #[serde(
        default = "default::denoise_prefilter",
        skip_serializing_if = "is_default::denoise_prefilter"
    )]
    pub denoise_prefilter: DenoisePrefilter,
    #[serde(
        default = "default::denoise_passes",
        skip_serializing_if = "is_default::denoise_passes"
    )]
    pub denoise_passes: DenoisePasses,
    #[serde(
        default = "default::denoise_quality",
        skip_serializing_if = "is_default::denoise_quality"
    )]
    pub denoise_quality: DenoiseQuality,
    #[serde(
        default = "default::light_tree",
        skip_serializing_if = "is_default::light_tree"
    )]
    pub light_tree: bool,
    /// The maps written beside colour and disparity, for both views. Recipe-wide: every sample
    /// of a dataset has the same files (a category cannot set it).
    #[serde(
        default = "default::outputs",
        skip_serializing_if = "is_default::outputs"
    )]
    pub outputs: Vec<OutputMap>,
}

/// Render keys a category sets for itself; each set key replaces the recipe's `[render]` one.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderOverride {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_bounces: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_filter: Option<PixelFilter>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter_width_px: Option<f64>,
    /// Turns adaptive sampling on for this category (with this threshold).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive_threshold: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive_min_samples: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise_prefilter: Option<DenoisePrefilter>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise_passes: Option<DenoisePasses>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub denoise_quality: Option<DenoiseQuality>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light_tree: Option<bool>,
}

impl RenderOverride {
    /// `base` with this category's keys in place of its own.
    pub fn apply(&self, base: &RenderRecipe) -> RenderRecipe {
        RenderRecipe {
            samples: self.samples.unwrap_or(base.samples),
            denoise: self.denoise.unwrap_or(base.denoise),
            max_bounces: self.max_bounces.unwrap_or(base.max_bounces),
            pixel_filter: self.pixel_filter.unwrap_or(base.pixel_filter),
            filter_width_px: self.filter_width_px.unwrap_or(base.filter_width_px),
            adaptive_threshold: self.adaptive_threshold.or(base.adaptive_threshold),
            adaptive_min_samples: self
                .adaptive_min_samples
                .unwrap_or(base.adaptive_min_samples),
            denoise_prefilter: self.denoise_prefilter.unwrap_or(base.denoise_prefilter),
            denoise_passes: self.denoise_passes.unwrap_or(base.denoise_passes),
            denoise_quality: self.denoise_quality.unwrap_or(base.denoise_quality),
            light_tree: self.light_tree.unwrap_or(base.light_tree),
            outputs: base.outputs.clone(),
        }
    }
}

impl RenderRecipe {
    /// The keys in the order they are written (the struct's order; checked by a test), which
    /// is also the order of a spec's `render`, with the scene's own keys in between.
    const KEYS: [&'static str; 12] = [
        "samples",
        "denoise",
        "max_bounces",
        "pixel_filter",
        "filter_width_px",
        "adaptive_threshold",
        "adaptive_min_samples",
        "denoise_prefilter",
        "denoise_passes",
        "denoise_quality",
        "light_tree",
        "outputs",
    ];
}

/// One scene's render settings: its category's recipe keys, and the scene's own draws.
///
/// Written (in `<id>.scene.json`) in the order of spec format 3: `samples`, `denoise`,
/// `cycles_seed`, `max_bounces`, `pixel_filter`, `filter_width_px`, `clip_start`, `clip_end`,
/// the optional recipe keys where set, `cycles_seed_right` where set.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderSettings {
    /// The recipe's `[render]` with the scene's category's own keys in place
    /// ([`Recipe::render_for`](crate::Recipe::render_for)).
    pub recipe: RenderRecipe,
    /// Cycles noise seed (of the left view's colour pass, and of the right one's when
    /// `cycles_seed_right` is absent).
    pub cycles_seed: u32,
    /// Camera clipping range in metres.
    pub clip_start: f64,
    pub clip_end: f64,
    /// The right view's Cycles noise seed: a real pair's two sensors have independent noise,
    /// and one seed for both views draws the same sampling noise at the same pixel of each, a
    /// pattern a network can learn to match. Absent (specs planned before it existed): both
    /// views use `cycles_seed`, as those specs were rendered.
    pub cycles_seed_right: Option<u32>,
}

impl RenderSettings {
    /// Every key with its value, the defaults of those a spec leaves out filled in (an old
    /// spec's right view takes `cycles_seed`, as it was rendered; adaptive sampling off is
    /// `null`): what the worker is sent, so it applies values and decides nothing.
    pub fn resolved(&self) -> Map<String, Value> {
        let mut m = match serde_json::to_value(self).expect("render settings serialise") {
            Value::Object(m) => m,
            _ => unreachable!("render settings serialise as an object"),
        };
        for (key, value) in defaults() {
            m.entry(key).or_insert(value);
        }
        m.entry("cycles_seed_right")
            .or_insert_with(|| self.cycles_seed_right.unwrap_or(self.cycles_seed).into());
        m
    }
}

impl Serialize for RenderSettings {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        // The recipe keys as the recipe writes them (those at their defaults left out) ...
        let keys = match serde_json::to_value(&self.recipe).map_err(S::Error::custom)? {
            Value::Object(m) => m,
            _ => return Err(S::Error::custom("render keys are not an object")),
        };
        // ... in their order, with the scene's keys where format 3 put them.
        let mut s = serializer.serialize_struct("RenderSettings", keys.len() + 4)?;
        for key in RenderRecipe::KEYS {
            if let Some(value) = keys.get(key) {
                s.serialize_field(key, value)?;
            }
            match key {
                "denoise" => s.serialize_field("cycles_seed", &self.cycles_seed)?,
                "filter_width_px" => {
                    s.serialize_field("clip_start", &self.clip_start)?;
                    s.serialize_field("clip_end", &self.clip_end)?;
                }
                _ => {}
            }
        }
        if let Some(seed) = self.cycles_seed_right {
            s.serialize_field("cycles_seed_right", &seed)?;
        }
        s.end()
    }
}

impl<'de> Deserialize<'de> for RenderSettings {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let mut keys = Map::<String, Value>::deserialize(deserializer)?;
        let mut take = |key: &str| keys.remove(key);
        fn parse<T: serde::de::DeserializeOwned, E: serde::de::Error>(
            key: &'static str,
            value: Option<Value>,
        ) -> Result<T, E> {
            let value = value.ok_or_else(|| E::missing_field(key))?;
            serde_json::from_value(value).map_err(|e| E::custom(format!("{key}: {e}")))
        }
        let cycles_seed = parse("cycles_seed", take("cycles_seed"))?;
        let clip_start = parse("clip_start", take("clip_start"))?;
        let clip_end = parse("clip_end", take("clip_end"))?;
        let cycles_seed_right = take("cycles_seed_right")
            .map(|v| parse("cycles_seed_right", Some(v)))
            .transpose()?;
        // What is left are the recipe's keys; an unknown one is refused there.
        let recipe = RenderRecipe::deserialize(Value::Object(keys)).map_err(D::Error::custom)?;
        Ok(Self {
            recipe,
            cycles_seed,
            clip_start,
            clip_end,
            cycles_seed_right,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AssetIndex, Recipe, plan_scene};

    /// Every optional key away from its default, so every key is written.
    fn every_key_set() -> RenderRecipe {
        RenderRecipe {
            samples: 8,
            denoise: true,
            max_bounces: 3,
            pixel_filter: PixelFilter::Gaussian,
            filter_width_px: 1.25,
            adaptive_threshold: Some(0.05),
            adaptive_min_samples: 4,
            denoise_prefilter: DenoisePrefilter::Fast,
            denoise_passes: DenoisePasses::Albedo,
            denoise_quality: DenoiseQuality::Balanced,
            light_tree: false,
            outputs: OutputMap::ALL.to_vec(),
        }
    }

    #[test]
    fn keys_list_the_recipe_fields_in_their_written_order() {
        let json = serde_json::to_string(&every_key_set()).unwrap();
        let mut at = 0;
        for key in RenderRecipe::KEYS {
            let found = json[at..]
                .find(&format!("\"{key}\":"))
                .unwrap_or_else(|| panic!("{key} after byte {at} of {json}"));
            at += found + 1;
        }
        let written: Map<String, Value> = serde_json::from_str(&json).unwrap();
        assert_eq!(written.len(), RenderRecipe::KEYS.len());
        // The table of defaults names keys of the recipe.
        assert!(defaults().keys().all(|k| written.contains_key(k)));
    }

    #[test]
    fn the_worker_gets_every_key_and_old_specs_resolve_to_how_they_rendered() {
        let spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
        let mut old = spec.render.clone();
        old.cycles_seed_right = None;
        old.recipe = RenderRecipe {
            adaptive_threshold: None,
            adaptive_min_samples: 0,
            denoise_prefilter: DenoisePrefilter::Accurate,
            denoise_passes: DenoisePasses::AlbedoNormal,
            denoise_quality: DenoiseQuality::High,
            light_tree: true,
            outputs: Vec::new(),
            ..old.recipe
        };
        let written = serde_json::to_value(&old).unwrap();
        assert!(written.get("light_tree").is_none() && written.get("cycles_seed_right").is_none());
        let r = old.resolved();
        assert_eq!(r.len(), RenderRecipe::KEYS.len() + 4, "{r:?}");
        assert_eq!(r["light_tree"], true);
        assert_eq!(r["adaptive_threshold"], Value::Null);
        assert_eq!(r["adaptive_min_samples"], 0);
        assert_eq!(r["denoise_prefilter"], "accurate");
        assert_eq!(r["denoise_passes"], "albedo_normal");
        assert_eq!(r["denoise_quality"], "high");
        assert_eq!(r["cycles_seed_right"], old.cycles_seed);
        // Set keys go as they are.
        let mut new = spec.render.clone();
        new.recipe = every_key_set();
        let r = new.resolved();
        assert_eq!(r["adaptive_threshold"], 0.05);
        assert_eq!(r["light_tree"], false);
        assert_eq!(r["cycles_seed_right"], new.cycles_seed_right.unwrap());
        assert_eq!(r["clip_end"], new.clip_end);
    }

    #[test]
    fn reading_refuses_unknown_and_missing_keys() {
        let spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
        let mut v = serde_json::to_value(&spec.render).unwrap();
        v["spp"] = 3.into();
        let e = serde_json::from_value::<RenderSettings>(v).unwrap_err();
        assert!(e.to_string().contains("unknown field `spp`"), "{e}");
        let mut v = serde_json::to_value(&spec.render).unwrap();
        v.as_object_mut().unwrap().remove("clip_end");
        let e = serde_json::from_value::<RenderSettings>(v).unwrap_err();
        assert!(e.to_string().contains("missing field `clip_end`"), "{e}");
    }
}
