use super::*;
use crate::{AssetIndex, Recipe, plan_scene};

fn json_value(spec: &SceneSpec) -> serde_json::Value {
    serde_json::from_str(&spec.to_json()).unwrap()
}

#[test]
fn json_carries_the_rig_camera_facts_and_reads_back() {
    let spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
    let v = json_value(&spec);
    assert_eq!(v["format_version"], SPEC_FORMAT_VERSION);
    let b = spec.rig.baseline_m;
    assert_eq!(v["cameras"]["left"]["position"][0].as_f64(), Some(-b / 2.0));
    assert_eq!(v["cameras"]["right"]["position"][0].as_f64(), Some(b / 2.0));
    assert_eq!(v["cameras"]["f_px"].as_f64(), Some(spec.rig.f_px()));
    assert_eq!(
        v["cameras"]["principal_point"][0].as_f64(),
        Some(f64::from(spec.rig.width) / 2.0)
    );
    assert_eq!(v["cameras"]["image_coordinates"], "pixel_corner_origin");
    assert_eq!(v["cameras"]["blender"]["sensor_fit"], "HORIZONTAL");
    assert_eq!(SceneSpec::from_json(&spec.to_json()).unwrap(), spec);
}

#[test]
fn each_view_gets_its_own_cycles_seed_and_old_specs_keep_one() {
    let recipe = Recipe::builtin_default();
    let assets = AssetIndex::default();
    let seeds: Vec<(u32, Option<u32>)> = (0..20)
        .map(|i| {
            let r = plan_scene(&recipe, &assets, 3, i).render;
            (r.cycles_seed, r.cycles_seed_right)
        })
        .collect();
    for &(left, right) in &seeds {
        let right = right.expect("a new plan has a right-view seed");
        assert_ne!(left, right);
    }
    // The right seeds differ from sample to sample, and are not the left ones shifted.
    let mut rights: Vec<u32> = seeds.iter().filter_map(|s| s.1).collect();
    rights.sort_unstable();
    rights.dedup();
    assert_eq!(rights.len(), seeds.len());
    let offsets: std::collections::BTreeSet<u32> = seeds
        .iter()
        .map(|&(l, r)| r.unwrap().wrapping_sub(l))
        .collect();
    assert!(offsets.len() > 1, "{seeds:?}");
    // Planning stays a pure function of (seed, index).
    assert_eq!(
        plan_scene(&recipe, &assets, 3, 7).render.cycles_seed_right,
        seeds[7].1
    );
    // A spec written before the key existed reads without it and writes none back: both views
    // render with `cycles_seed`, as they were rendered.
    let mut v = json_value(&plan_scene(&recipe, &assets, 3, 0));
    v["render"]
        .as_object_mut()
        .unwrap()
        .remove("cycles_seed_right");
    let old = SceneSpec::from_json(&v.to_string()).unwrap();
    assert_eq!(old.render.cycles_seed_right, None);
    assert!(
        json_value(&old)["render"]
            .get("cycles_seed_right")
            .is_none()
    );
}

#[test]
fn render_keys_added_later_are_written_only_when_set_and_reach_the_spec() {
    // A spec without them (every dataset made before) reads back to Cycles' old behaviour.
    let spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
    let mut v = json_value(&spec);
    for key in [
        "adaptive_threshold",
        "adaptive_min_samples",
        "denoise_prefilter",
        "denoise_passes",
        "denoise_quality",
        "light_tree",
    ] {
        v["render"].as_object_mut().unwrap().remove(key);
    }
    let old = SceneSpec::from_json(&v.to_string()).unwrap();
    assert_eq!(old.render.recipe.adaptive_threshold, None);
    assert!(old.render.recipe.light_tree);
    assert_eq!(
        old.render.recipe.denoise_passes,
        DenoisePasses::AlbedoNormal
    );
    let render = json_value(&old)["render"].clone();
    assert!(render.get("light_tree").is_none() && render.get("denoise_prefilter").is_none());

    let text = crate::recipe::PRESETS[0].1.replace(
        "[render]\n",
        "[render]\nadaptive_threshold = 0.05\nadaptive_min_samples = 4\n\
         denoise_prefilter = \"fast\"\ndenoise_passes = \"albedo\"\n\
         denoise_quality = \"balanced\"\nlight_tree = false\n",
    );
    let recipe = Recipe::from_toml_str(&text, "x.toml").unwrap();
    let spec = plan_scene(&recipe, &AssetIndex::default(), 1, 2);
    let render = json_value(&spec)["render"].clone();
    assert_eq!(render["adaptive_threshold"], 0.05);
    assert_eq!(render["adaptive_min_samples"], 4);
    assert_eq!(render["denoise_prefilter"], "fast");
    assert_eq!(render["denoise_passes"], "albedo");
    assert_eq!(render["denoise_quality"], "balanced");
    assert_eq!(render["light_tree"], false);
    assert_eq!(SceneSpec::from_json(&spec.to_json()).unwrap(), spec);

    for (bad, key) in [
        ("adaptive_threshold = 0.0", "render.adaptive_threshold"),
        (
            "adaptive_min_samples = 100000",
            "render.adaptive_min_samples",
        ),
    ] {
        let text = crate::recipe::PRESETS[0]
            .1
            .replace("[render]\n", &format!("[render]\n{bad}\n"));
        let err = Recipe::from_toml_str(&text, "x.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains(key), "{err}");
    }
}

#[test]
fn version_2_specs_without_cameras_still_read() {
    let spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
    let mut v = json_value(&spec);
    v.as_object_mut().unwrap().remove("cameras");
    v["format_version"] = 2.into();
    let back = SceneSpec::from_json(&v.to_string()).unwrap();
    assert_eq!(back, spec);
    assert_eq!(json_value(&back)["cameras"], json_value(&spec)["cameras"]);
}

#[test]
fn cameras_that_disagree_with_the_rig_or_a_newer_version_are_refused() {
    let spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
    let mut v = json_value(&spec);
    v["rig"]["baseline_m"] = (spec.rig.baseline_m * 2.0).into();
    let err = SceneSpec::from_json(&v.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("`cameras` disagree"), "{err}");
    let mut v = json_value(&spec);
    v["format_version"] = (SPEC_FORMAT_VERSION + 1).into();
    let err = SceneSpec::from_json(&v.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("newer"), "{err}");
}
