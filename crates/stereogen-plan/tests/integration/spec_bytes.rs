//! Specs and recipes keep their bytes: the JSON of planned specs and each preset's fingerprint
//! are pinned to what they were before the render settings became one type from recipe to spec
//! (a change here would make old datasets resume into different specs and re-render differently).

use sha2::{Digest, Sha256};
use stereogen_plan::recipe::PRESETS;
use stereogen_plan::{AssetIndex, Recipe, SceneSpec, plan_scene};

/// (preset, SHA-256 of the JSON of its samples 0..40 of seed 7 one after another, fingerprint).
const PINNED: [(&str, &str, &str); 6] = [
    (
        "crestereo",
        "e1e24398dc27505a950f93bbafeef86107a7c4282abf40d12d0bfbd1b524be6d",
        "aea0a5185437ba7f",
    ),
    (
        "shapenet",
        "f063c88ce2d245a5da8a748d6925117916e483ab3285ce1176b9d388ff2504c9",
        "969a8f7542e5c538",
    ),
    (
        "tree",
        "96086bdcaddecb566f4b7a34fb00a101a28f9132b3d73db4d03d18409c1e84fa",
        "be62a36183584c6f",
    ),
    (
        "hole",
        "f8009009a38eb250594c358db033b9eef1d5c2731ba3135a3635388adfe77daf",
        "22106eca181b4bce",
    ),
    (
        "reflective",
        "98f4812c0d7e1f17e9debbb1ef76e525554d5eb8927539f0ca40cdeba6e470be",
        "c8766a98f1b0e276",
    ),
    (
        "wmgstereo",
        "9daa7d4a4aecae65267628e87e066cfc323695c8a1e7ef2a233b98db8b0baf66",
        "ce8f70d37cdd6848",
    ),
];

#[test]
fn planned_specs_and_recipe_fingerprints_keep_their_bytes() {
    assert_eq!(PRESETS.len(), PINNED.len());
    for (name, specs, fingerprint) in PINNED {
        let recipe = Recipe::preset(name).unwrap();
        let mut h = Sha256::new();
        for i in 0..40 {
            let json = plan_scene(&recipe, &AssetIndex::default(), 7, i).to_json();
            assert_eq!(
                SceneSpec::from_json(&json).unwrap().to_json(),
                json,
                "{name} sample {i} reads back to the same bytes"
            );
            h.update(json.as_bytes());
        }
        let digest: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(digest, specs, "the specs of preset {name}");
        assert_eq!(recipe.fingerprint(), fingerprint, "preset {name}");
    }
}

#[test]
fn a_spec_without_the_later_render_keys_writes_none_of_them_in_format_3_order() {
    let mut spec = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 2);
    // As a spec planned before those keys existed reads.
    spec.render.cycles_seed_right = None;
    let r = &mut spec.render.recipe;
    r.adaptive_threshold = None;
    r.adaptive_min_samples = 0;
    r.denoise_prefilter = Default::default();
    r.denoise_passes = Default::default();
    r.denoise_quality = Default::default();
    r.light_tree = true;
    let json = spec.to_json();
    let render = &json[json.find("\"render\"").unwrap()..json.find("\"world\"").unwrap()];
    let keys: Vec<&str> = render
        .lines()
        .skip(1)
        .filter_map(|l| l.trim().strip_prefix('"')?.split('"').next())
        .collect();
    assert_eq!(
        keys,
        [
            "samples",
            "denoise",
            "cycles_seed",
            "max_bounces",
            "pixel_filter",
            "filter_width_px",
            "clip_start",
            "clip_end"
        ],
        "{render}"
    );
    assert_eq!(SceneSpec::from_json(&json).unwrap().to_json(), json);
}
