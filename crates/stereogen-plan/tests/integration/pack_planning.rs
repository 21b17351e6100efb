//! Planning with the built-in content pack: the default recipe draws the pack's photos and meshes
//! (procedural textures and primitives stay classes among them), and a plan is a pure function of
//! (recipe, seed, index, asset index).

use std::path::PathBuf;

use stereogen_plan::spec::{BaseColor, Shape};
use stereogen_plan::{AssetIndex, MeshAsset, Recipe, SceneSpec, TextureAsset, plan_scene};

/// An index shaped like the installed pack's (what `stereogen-assets` fills in).
fn pack_index(root: &str) -> AssetIndex {
    let photo = |name: &str, size: [u32; 2]| TextureAsset {
        path: PathBuf::from(format!("{root}/skimage/data/{name}")),
        size: Some(size),
    };
    let mesh = |name: &str| MeshAsset {
        path: PathBuf::from(format!("{root}/pyvista/examples/{name}")),
        synset: None,
        label: None,
    };
    AssetIndex {
        textures: vec![
            photo("brick.png", [512, 512]),
            photo("grass.png", [512, 512]),
            photo("coffee.png", [600, 400]),
            photo("astronaut.png", [512, 512]),
        ],
        pack_meshes: vec![mesh("airplane.ply"), mesh("ant.ply"), mesh("nut.ply")],
        fingerprint: Some("0123456789abcdef".into()),
        ..AssetIndex::default()
    }
}

fn objects(spec: &SceneSpec) -> impl Iterator<Item = &stereogen_plan::spec::ObjectSpec> {
    spec.objects.iter()
}

fn is_photo(o: &stereogen_plan::spec::ObjectSpec) -> bool {
    matches!(o.material.base, BaseColor::Image { .. })
}

#[test]
fn the_default_preset_asks_for_the_pack_and_a_procedural_recipe_can_opt_out() {
    let r = Recipe::builtin_default();
    assert!(r.sources.builtin_pack);
    assert!(r.materials.procedural_share > 0.0 && r.materials.procedural_share < 1.0);
    assert!(r.materials.photo_texel_px.is_some());
    let text = toml::to_string(&r)
        .unwrap()
        .replace("builtin_pack = true", "builtin_pack = false");
    let procedural: Recipe = toml::from_str(&text).unwrap();
    assert!(!procedural.sources.builtin_pack);
}

#[test]
fn default_plans_draw_pack_photos_and_meshes_among_procedural_content() {
    let recipe = Recipe::builtin_default();
    let assets = pack_index("/pack/site");
    let (mut photos, mut procedural, mut pack_meshes, mut primitives, mut samples_with_both) =
        (0, 0, 0, 0, 0);
    for index in 0..40 {
        let spec = plan_scene(&recipe, &assets, 3, index);
        let mut has = (false, false);
        for o in objects(&spec) {
            match &o.material.base {
                BaseColor::Image { path, scale, .. } => {
                    assert!(
                        assets.textures.iter().any(|t| &t.path == path),
                        "{}",
                        path.display()
                    );
                    assert!(scale.is_finite() && *scale > 0.0);
                    photos += 1;
                    has.0 = true;
                }
                BaseColor::Procedural { .. } => procedural += 1,
                BaseColor::Flat { .. } => {}
            }
            if o.source == "pack" {
                let Shape::MeshFile { candidates, .. } = &o.shape else {
                    panic!("a pack object is a mesh file: {:?}", o.shape)
                };
                assert!(
                    candidates
                        .iter()
                        .all(|c| assets.pack_meshes.iter().any(|m| &m.path == c))
                );
                pack_meshes += 1;
                has.1 = true;
            }
            if o.source == "primitive" {
                primitives += 1;
            }
        }
        samples_with_both += usize::from(has.0 && has.1);
    }
    assert!(
        photos > 2 * procedural && procedural > 0,
        "{photos} photo, {procedural} procedural surfaces"
    );
    assert!(
        pack_meshes > 20 && primitives > 20,
        "{pack_meshes} pack meshes, {primitives} primitives"
    );
    assert!(
        samples_with_both >= 5,
        "{samples_with_both} samples with a pack photo and a pack mesh"
    );
    // The background is a photo too (most of the image).
    assert!((0..10).any(|i| {
        plan_scene(&recipe, &assets, 3, i)
            .objects
            .iter()
            .any(|o| o.name == "background" && is_photo(o))
    }));
}

#[test]
fn a_plan_is_a_pure_function_of_recipe_seed_index_and_asset_index() {
    let recipe = Recipe::builtin_default();
    let a = pack_index("/pack/site");
    for index in 0..8 {
        assert_eq!(
            plan_scene(&recipe, &a, 11, index).to_json(),
            plan_scene(&recipe, &a.clone(), 11, index).to_json()
        );
    }
    // The same pack installed elsewhere: the same plan, with only the root of the paths changed.
    let b = pack_index("/elsewhere/site");
    for index in 0..8 {
        assert_eq!(
            plan_scene(&recipe, &a, 11, index)
                .to_json()
                .replace("/pack/site", "/elsewhere/site"),
            plan_scene(&recipe, &b, 11, index).to_json()
        );
    }
    // Another pack content gives other plans: this is why datasets record the fingerprint.
    let mut fewer = a.clone();
    fewer.textures.pop();
    assert!((0..8).any(|i| plan_scene(&recipe, &a, 11, i) != plan_scene(&recipe, &fewer, 11, i)));
}

#[test]
fn without_the_pack_plans_stay_procedural() {
    let recipe = Recipe::builtin_default();
    for index in 0..10 {
        let spec = plan_scene(&recipe, &AssetIndex::default(), 5, index);
        assert!(spec.objects.iter().all(|o| !is_photo(o)
            && o.source != "pack"
            && !matches!(o.shape, Shape::MeshFile { .. })));
    }
}

#[test]
fn photos_are_sized_to_the_screen() {
    // A small photo stretched over the whole background would be blurry: the planner tiles it.
    let recipe = Recipe::builtin_default();
    let [_, hi] = recipe.materials.photo_texel_px.unwrap();
    let mut assets = pack_index("/p");
    assets.textures = vec![TextureAsset {
        path: "/p/small.png".into(),
        size: Some([64, 64]),
    }];
    let spec = (0..20)
        .map(|i| plan_scene(&recipe, &assets, 1, i))
        .find(|s| {
            s.objects
                .iter()
                .any(|o| o.name == "background" && is_photo(o))
        })
        .expect("a photo background");
    let bg = spec
        .objects
        .iter()
        .find(|o| o.name == "background")
        .unwrap();
    let BaseColor::Image { scale, .. } = bg.material.base else {
        unreachable!()
    };
    let screen_px = f64::from(spec.rig.width.max(spec.rig.height));
    // One repeat spans screen_px / (2 scale) pixels; no more than `hi` per photo pixel.
    assert!(
        screen_px / (2.0 * scale) / 64.0 <= hi * 1.01,
        "scale {scale} on a {screen_px} px wide background"
    );
}

#[test]
fn the_pack_keys_are_checked_and_named() {
    let text = stereogen_plan::recipe::PRESETS
        .iter()
        .find(|(n, _)| *n == "crestereo")
        .unwrap()
        .1;
    let bad = |from: &str, to: &str| {
        Recipe::from_toml_str(&text.replace(from, to), "x.toml")
            .unwrap_err()
            .to_string()
    };
    let err = bad("pack_mesh_share = 0.5", "pack_mesh_share = 1.5");
    assert!(
        err.contains("sources.pack_mesh_share") && err.contains("1.5"),
        "{err}"
    );
    let err = bad("procedural_share = 0.25", "procedural_share = -0.1");
    assert!(err.contains("materials.procedural_share"), "{err}");
    let err = bad("photo_texel_px = [0.5, 1.5]", "photo_texel_px = [2.0, 1.0]");
    assert!(err.contains("materials.photo_texel_px"), "{err}");
    let err = bad("exclude_licences = []", "exclude_licences = [\" \"]");
    assert!(err.contains("sources.exclude_licences"), "{err}");
}
