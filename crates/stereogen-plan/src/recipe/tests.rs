use super::*;
use crate::render::DenoisePrefilter;

#[test]
fn a_category_render_key_replaces_the_recipe_one_and_is_checked() {
    let recipe = Recipe::builtin_default();
    let assets = crate::AssetIndex::default();
    let mut seen = BTreeMap::new();
    for index in 0..40 {
        let spec = crate::plan_scene(&recipe, &assets, 5, index);
        let r = spec.render.recipe;
        let expected = match spec.category.as_str() {
            "reflective" => (24, None, DenoisePrefilter::Accurate),
            "shapenet" => (32, Some(0.02), DenoisePrefilter::Accurate),
            "tree" | "hole" => (32, None, DenoisePrefilter::Fast),
            other => panic!("category {other}"),
        };
        assert_eq!(
            (r.samples, r.adaptive_threshold, r.denoise_prefilter),
            expected,
            "{}",
            spec.category
        );
        // Keys the category leaves alone come from [render].
        assert!(r.denoise && r.max_bounces == recipe.render.max_bounces);
        *seen.entry(spec.category).or_insert(0) += 1;
    }
    assert_eq!(seen.len(), 4, "{seen:?}");

    let text = PRESETS[0].1;
    let with = |line: &str| text.replacen("render = { samples = 24 }", line, 1);
    let e = parse_error(&with("render = { samples = 0 }"));
    assert!(e.contains("categories[3].render.samples"), "{e}");
    let e = parse_error(&with("render = { adaptive_min_samples = 40 }"));
    assert!(
        e.contains("categories[3].render.adaptive_min_samples"),
        "{e}"
    );
    let e = parse_error(&with("render = { spp = 8 }"));
    assert!(e.contains("spp"), "{e}");
    // A recipe without them (every recipe written before) renders every category with [render].
    let old = Recipe::from_toml_str(&with(""), "x.toml").unwrap();
    let reflective = old
        .categories
        .iter()
        .find(|c| c.name == "reflective")
        .unwrap();
    assert_eq!(old.render_for(reflective), old.render);
}

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

/// The error reading `text` as a recipe, as a person sees it.
fn parse_error(text: &str) -> String {
    Recipe::from_toml_str(text, "x.toml")
        .unwrap_err()
        .to_string()
}

/// The error reading the default recipe with `from` replaced by `to`.
fn error_with(from: &str, to: &str) -> String {
    parse_error(&default_text().replace(from, to))
}

#[test]
fn unknown_key_is_named_with_its_line() {
    let text = default_text().replace("[render]", "[render]\nspp = 3");
    let err = parse_error(&text);
    assert!(
        err.contains("unknown field `spp`") && err.contains("line"),
        "{err}"
    );
    assert!(!err.contains('\n'), "{err}");
}

#[test]
fn missing_key_is_named() {
    // The first `samples =` is `[render]`'s (a category's inline `render = { samples = .. }`
    // stays).
    let text = default_text().replacen("samples = ", "# samples = ", 1);
    let err = parse_error(&text);
    assert!(err.contains("missing field `samples`"), "{err}");
}

#[test]
fn bad_distribution_is_named() {
    let text = default_text().replace(
        "focal_mm = { dist = \"uniform\"",
        "focal_mm = { dist = \"cauchy\"",
    );
    let err = parse_error(&text);
    assert!(err.contains("unknown variant `cauchy`"), "{err}");
}

#[test]
fn out_of_range_values_name_key_and_bounds() {
    let err = error_with("width = 960", "width = 4");
    assert!(
        err.contains("camera.width") && err.contains("16..=16384"),
        "{err}"
    );
    let err = error_with("boolean_probability = 0.25", "boolean_probability = 1.5");
    assert!(err.contains("primitives.boolean_probability"), "{err}");
    // A bound derived from the width prints as the number a person would write.
    let err = error_with("width = 960", "width = 96");
    assert!(
        err.contains("placement.disparity_px") && err.contains("76.8") && !err.contains("76.80000"),
        "{err}"
    );
}

/// The keys the presets set to a value other than their default: leaving them out changes
/// the recipe.
const SET_OTHERWISE_BY_THE_PRESETS: [&str; 3] = [
    "sources.builtin_pack",
    "materials.procedural_share",
    "materials.photo_texel_px",
];

/// The key as written in a TOML table: `lights.near_factor` → `near_factor`,
/// `trees.leaf_rgb (red)` → `leaf_rgb`.
fn toml_name(key: &str) -> &str {
    let leaf = key.rsplit('.').next().unwrap_or(key);
    leaf.split(' ').next().unwrap_or(leaf)
}

fn without_keys(text: &str, names: &[&str]) -> String {
    text.lines()
        .filter(|l| {
            !names
                .iter()
                .any(|k| l.trim_start().starts_with(&format!("{k} =")))
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// A preset with the keys of `added_keys!` removed: what recipes written before them look like.
/// The keys come from the recipe's check rows (`with_default`), the one list of keys.
fn without_added_keys(text: &str) -> String {
    let preset = Recipe::builtin_default();
    let checks = validate::recipe_checks(&preset);
    let added: Vec<&str> = checks
        .iter()
        .filter(|c| c.has_default && !SET_OTHERWISE_BY_THE_PRESETS.contains(&&*c.key))
        .map(|c| toml_name(&c.key))
        .collect();
    without_keys(text, &added)
}

#[test]
fn the_rows_with_a_default_are_exactly_the_keys_a_recipe_may_leave_out() {
    let text = default_text();
    let preset = Recipe::builtin_default();
    for check in validate::recipe_checks(&preset) {
        let Some((section, _)) = check.key.split_once('.') else {
            continue;
        };
        if section.starts_with("categories") {
            continue;
        }
        let name = toml_name(&check.key);
        let left_out = without_keys(text, &[name]);
        assert_ne!(left_out, text, "{}: the preset states it", check.key);
        let parsed = Recipe::from_toml_str(&left_out, "x.toml");
        if check.has_default {
            let parsed = parsed.unwrap_or_else(|e| panic!("{}: {e}", check.key));
            let expected = !SET_OTHERWISE_BY_THE_PRESETS.contains(&&*check.key);
            assert_eq!(parsed == preset, expected, "{}", check.key);
        } else {
            let e = match parsed {
                Ok(_) => panic!("{}: left out, yet the recipe parses", check.key),
                Err(e) => e.to_string(),
            };
            assert!(e.contains(&format!("missing field `{name}`")), "{e}");
        }
    }
}

#[test]
fn recipes_without_the_added_keys_read_as_the_presets_and_keep_their_fingerprint() {
    for (name, text) in PRESETS {
        let old = without_added_keys(text);
        assert_ne!(
            old.len(),
            text.len(),
            "{name}: the preset states the added keys"
        );
        let old = Recipe::from_toml_str(&old, name).unwrap();
        let preset = Recipe::preset(name).unwrap();
        assert_eq!(old, preset, "{name}");
        // Defaults are not serialised, so the fingerprint is the one of the recipe before the keys existed.
        let json = serde_json::to_string(&preset).unwrap();
        assert!(
            !json.contains("clip_end_factor") && !json.contains("leaf_rgb"),
            "{json}"
        );
    }
}

#[test]
fn added_keys_are_checked_and_named() {
    let err = error_with("color_channel = [0.2, 1.0]", "color_channel = [0.2, 1.5]");
    assert!(
        err.contains("lights.color_channel") && err.contains("1.5"),
        "{err}"
    );
    let err = error_with("clip_end_factor = 2.0", "clip_end_factor = 0.5");
    assert!(err.contains("camera.clip_end_factor"), "{err}");
    let err = error_with("mesh_candidates = 3", "mesh_candidates = 0");
    assert!(err.contains("sources.mesh_candidates"), "{err}");
    let set = Recipe::from_toml_str(
        &default_text().replace("background_oversize = 1.15", "background_oversize = 1.5"),
        "x.toml",
    )
    .unwrap();
    assert_ne!(set.fingerprint(), Recipe::builtin_default().fingerprint());
}

#[test]
fn outputs_name_each_map_at_most_once() {
    let with =
        |line: &str| default_text().replacen("[render]\n", &format!("[render]\n{line}\n"), 1);
    let r = Recipe::from_toml_str(&with("outputs = [\"semantic\", \"depth\"]"), "x.toml").unwrap();
    assert_eq!(
        r.render.outputs,
        vec![crate::OutputMap::Semantic, crate::OutputMap::Depth]
    );
    let e = parse_error(&with("outputs = [\"depth\", \"normals\", \"depth\"]"));
    assert!(
        e.contains("render.outputs")
            && e.contains("at most once")
            && e.contains("[depth, normals, depth]"),
        "{e}"
    );
    let e = parse_error(&with("outputs = [\"albedo\"]"));
    assert!(e.contains("albedo") && e.contains("`depth`"), "{e}");
}
