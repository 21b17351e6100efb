//! The `wmgstereo` preset's backgrounds rendered by the real worker: a small dataset (every
//! category, walls, rooms and skies, every map) passes `audit --check` at every pixel and
//! `stats --check`; rooms close the view (every pixel sees a surface), furniture and the room's
//! surfaces show in the instance maps, and a sky lights what it leaves without a surface.

use std::collections::BTreeSet;
use std::path::Path;

use stereo_io::{MapKind, read_id_png};
use stereogen::dataset::{Manifest, read_scene_spec};
use stereogen::plan::{
    BackgroundKind, Dist, HdriSpec, Modifier, OutputMap, Recipe, SEMANTIC_CLASSES, STUDIO_HDRIS,
};
use stereogen::render::RenderService;
use stereogen::validate::audit::geometry::read_geometry;
use test_support::{audit_cmd, generate_cmd, run_ok, run_shown, stats_cmd, worker_config};

/// The preset at 96×54 with 2 samples per pixel and every map; the disparity law scaled with the
/// width (the preset's is for 960 px); fewer objects, so a scene renders in about a second.
fn tiny_wmgstereo(dir: &Path) -> std::path::PathBuf {
    let mut r = Recipe::preset("wmgstereo").unwrap();
    r.camera.width = 96;
    r.camera.height = 54;
    r.render.samples = 2;
    r.render.denoise = false;
    r.render.outputs = OutputMap::ALL.to_vec();
    r.placement.disparity_px = Dist::uniform(2.0, 24.0);
    for c in &mut r.categories {
        c.render = None;
        c.objects = stereogen::plan::recipe::CountRange { min: 2, max: 4 };
    }
    let path = dir.join("wmgstereo_tiny.toml");
    std::fs::write(&path, toml::to_string(&r).unwrap()).unwrap();
    path
}

fn class_id(name: &str) -> u16 {
    SEMANTIC_CLASSES.iter().position(|c| *c == name).unwrap() as u16 + 1
}

#[test]
fn rooms_and_skies_render_exact_ground_truth_and_pass_the_checks() {
    let tmp = tempfile::tempdir().unwrap();
    let recipe = tiny_wmgstereo(tmp.path());
    let data = tmp.path().join("data");
    // Seed 6, 8 scenes: all four categories and all three background kinds (`stereogen plan`).
    run_ok(generate_cmd(&recipe, &data, 8).args(["--seed", "6"]));
    let entries = Manifest::read(&data.join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len(), 8);
    let (mut categories, mut kinds) = (BTreeSet::new(), BTreeSet::new());
    for e in &entries {
        let spec = read_scene_spec(&data.join(&e.files.scene)).unwrap();
        categories.insert(spec.category.clone());
        let what = format!("{} ({})", e.id, e.category);
        let (left, _) = stereo_io::read_disparity_exr(&data.join(&e.files.disp_left)).unwrap();
        let valid = left.valid.iter().filter(|v| **v).count() as f64 / left.valid.len() as f64;
        let instance =
            read_id_png(&data.join(e.files.map(MapKind::Instance, "left").unwrap())).unwrap();
        let semantic =
            read_id_png(&data.join(e.files.map(MapKind::Semantic, "left").unwrap())).unwrap();
        let classes: BTreeSet<u16> = semantic.data.iter().copied().collect();
        let kind = spec.background_kind();
        kinds.insert(kind);
        if kind == BackgroundKind::Environment {
            // The sky shows (no surface) above the ground, and lights the scene: the image's
            // top row is not black.
            assert!(valid < 1.0, "{what}: no sky visible");
            assert!(classes.contains(&class_id("ground")), "{what}: {classes:?}");
            let img = stereo_io::read_rgb(&data.join(&e.files.left)).unwrap();
            let top: u64 = img.data[..img.width * 3]
                .iter()
                .map(|&c| u64::from(c))
                .sum();
            assert!(top > 0, "{what}: the sky is black");
        } else if kind == BackgroundKind::Room {
            // A closed room: every pixel sees a surface.
            assert_eq!(valid, 1.0, "{what}: pixels see past the room");
            assert!(classes.contains(&class_id("room")), "{what}: {classes:?}");
            assert!(
                !instance.data.contains(&0),
                "{what}: pixels without an object"
            );
        } else {
            assert!(classes.contains(&class_id("wall")), "{what}: {classes:?}");
        }
    }
    assert_eq!(categories.len(), 4, "{categories:?}");
    assert_eq!(kinds.len(), 3, "{kinds:?}");

    furniture_stands_on_the_floor(&data, &entries);

    let (o, text) = run_shown(audit_cmd(&data).args(["--all", "--every-pixel", "--check"]));
    assert!(o.status.success(), "audit --check failed:\n{text}");
    let (o, text) = run_shown(
        stats_cmd(&data)
            .args(["--check", "--out"])
            .arg(tmp.path().join("stats")),
    );
    assert!(o.status.success(), "stats --check failed:\n{text}");
}

/// Blender's geometry of every room scene: each piece of furniture's lowest point lies on the
/// floor (a flat mesh placed by its bounding sphere would float), and none reaches below it.
fn furniture_stands_on_the_floor(data: &Path, entries: &[stereo_io::ManifestEntry]) {
    let mut service = RenderService::new(worker_config());
    let mut checked = 0;
    for e in entries {
        let spec = read_scene_spec(&data.join(&e.files.scene)).unwrap();
        let floor = spec.objects.iter().find(|o| o.name == "room_floor");
        let Some(floor) = floor else { continue };
        let floor_y = floor.location[1];
        let exported = service.export_geometry(&spec).unwrap();
        let geometry = read_geometry(&exported.reply.file).unwrap();
        for (i, o) in geometry.objects.iter().enumerate() {
            let Some(planned) = spec.objects.iter().find(|p| p.name == o.name) else {
                continue;
            };
            if planned.source != "furniture" {
                continue;
            }
            assert!(
                planned
                    .modifiers
                    .iter()
                    .any(|m| matches!(m, Modifier::RestOnFloor { y } if *y == floor_y)),
                "{}: {:?}",
                o.name,
                planned.modifiers
            );
            let lowest = geometry
                .scene
                .triangles
                .iter()
                .filter(|t| t.object == i)
                .flat_map(|t| t.v.iter().map(|p| p[1]))
                .fold(f64::INFINITY, f64::min);
            let tolerance = 1e-5 * floor_y.abs().max(1.0);
            assert!(
                (lowest - floor_y).abs() <= tolerance,
                "{} {}: lowest point at y = {lowest}, the floor at {floor_y}",
                e.id,
                o.name
            );
            checked += 1;
        }
    }
    assert!(checked > 0, "no furniture in the room scenes");
    println!("{checked} pieces of furniture stand on their floor");
}

/// Every HDR map Blender ships, around the same environment scene: each loads and lights the
/// scene (its images differ from map to map, the top row is not black), and the ground truth does
/// not depend on the map (both disparity maps the same bytes under all eight).
#[test]
fn every_hdr_map_lights_an_environment_and_leaves_the_ground_truth_alone() {
    let base = test_support::one_spec_per_background(6, (96, 54), 2, &[])
        .into_iter()
        .find(|s| s.background_kind() == BackgroundKind::Environment)
        .unwrap();
    let mut service = RenderService::new(worker_config());
    let mut disparity = None;
    let mut means = Vec::new();
    for name in STUDIO_HDRIS {
        let mut spec = base.clone();
        spec.world.sky = None;
        spec.world.hdri = Some(HdriSpec {
            name: name.into(),
            rotation: 0.7,
            strength: 1.0,
        });
        stereogen::plan::check_scene_spec(&spec).unwrap();
        let pair = test_support::render(&mut service, &spec);
        let valid = pair.left.valid.iter().filter(|v| **v).count();
        assert!(valid < pair.left.valid.len(), "{name}: no backdrop visible");
        let maps = (pair.left.data.clone(), pair.right.data.clone());
        match &disparity {
            None => disparity = Some(maps),
            Some(first) => assert!(*first == maps, "{name}: the disparity changed with the map"),
        }
        let img = stereo_io::read_rgb(&pair.layout.abs(&pair.entry.files.left)).unwrap();
        let top: u64 = img.data[..img.width * 3]
            .iter()
            .map(|&c| u64::from(c))
            .sum();
        assert!(top > 0, "{name}: the top row is black");
        let mean: u64 = img.data.iter().map(|&c| u64::from(c)).sum::<u64>() / img.data.len() as u64;
        means.push((name, mean, img.data));
    }
    for (i, (a, _, x)) in means.iter().enumerate() {
        for (b, _, y) in &means[i + 1..] {
            assert!(x != y, "{a} and {b} render the same image");
        }
    }
    println!(
        "mean level per HDR map: {:?}",
        means.iter().map(|(n, m, _)| (*n, *m)).collect::<Vec<_>>()
    );
}
