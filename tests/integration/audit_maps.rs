//! `stereogen audit --check` on the maps beside the disparity (depth, normals, instance,
//! semantic), rendered by the real generator with real Blender: every map of every category of
//! the default preset passes against the audit's own ray cast, and a copy whose depth is 1% off,
//! whose normals are turned round, or whose instance ids are wrong in a region fails, each sample
//! named with the map, while the untouched samples still pass. The corrupted files are re-signed
//! in the manifest, so it is the geometry, not the checksum, that catches them.

use std::path::{Path, PathBuf};

use stereo_io::MapKind;
use stereogen::dataset::{DatasetLayout, Manifest, ManifestEntry};
use stereogen::plan::OutputMap;
use test_support::files::copy_dir;
use test_support::{
    audit_cmd, audit_report, audit_samples_by_id, generate_cmd, resign, run_ok, run_shown,
    tiny_recipe,
};

/// With seed 3 the first 8 scenes of the tiny `crestereo` mix cover all four categories.
const SCENES: u64 = 8;
const SEED: u64 = 3;

/// The tiny default preset with every map, rendered into `dir/name`.
fn generate_with_maps(dir: &Path, name: &str) -> PathBuf {
    let mut recipe = tiny_recipe("crestereo");
    recipe.render.outputs = OutputMap::ALL.to_vec();
    let path = dir.join("tiny-maps.toml");
    std::fs::write(&path, toml::to_string(&recipe).unwrap()).unwrap();
    let out = dir.join(name);
    run_ok(generate_cmd(&path, &out, SCENES).args(["--seed", &SEED.to_string()]));
    out
}

fn audit(data: &Path) -> (std::process::Output, String) {
    run_shown(audit_cmd(data).args(["--all", "--every-pixel", "--check"]))
}

/// The block of pixels the corruptions change: the middle half of the image in both directions.
fn in_block(i: usize, w: usize, h: usize) -> bool {
    let (x, y) = (i % w, i / w);
    (w / 4..3 * w / 4).contains(&x) && (h / 4..3 * h / 4).contains(&y)
}

fn map_path(data: &Path, e: &ManifestEntry, kind: MapKind, view: &str) -> PathBuf {
    DatasetLayout::new(data).abs(e.files.map(kind, view).expect("the sample has the map"))
}

/// Scales the depth of every surface pixel of the block by 1.01; returns how many.
fn scale_depth(data: &Path, e: &ManifestEntry) -> usize {
    let path = map_path(data, e, MapKind::Depth, "left");
    let mut m = stereo_io::read_depth_exr(&path).unwrap();
    let (w, h) = (m.width, m.height);
    let mut n = 0;
    for (i, d) in m.data.iter_mut().enumerate() {
        if *d > 0.0 && in_block(i, w, h) {
            *d *= 1.01;
            n += 1;
        }
    }
    stereo_io::write_depth_exr(&path, &m, "left").unwrap();
    resign(data, &e.id, &MapKind::Depth.file_key("left"));
    n
}

/// Turns the normal of every surface pixel of the block round; returns how many.
fn flip_normals(data: &Path, e: &ManifestEntry) -> usize {
    let path = map_path(data, e, MapKind::Normals, "right");
    let mut m = stereo_io::read_normals_exr(&path).unwrap();
    let (w, h) = (m.width, m.height);
    let mut n = 0;
    for (i, v) in m.data.iter_mut().enumerate() {
        if *v != [0.0; 3] && in_block(i, w, h) {
            *v = v.map(|c| -c);
            n += 1;
        }
    }
    stereo_io::write_normals_exr(&path, &m, "right").unwrap();
    resign(data, &e.id, &MapKind::Normals.file_key("right"));
    n
}

/// Gives every surface pixel of the block another object's instance id; returns how many.
fn swap_instances(data: &Path, e: &ManifestEntry) -> usize {
    let path = map_path(data, e, MapKind::Instance, "left");
    let mut m = stereo_io::read_id_png(&path).unwrap();
    let (w, h) = (m.width, m.height);
    let ids = e.instances.len() as u16;
    assert!(ids >= 2, "a scene of one object cannot swap ids");
    let mut n = 0;
    for (i, id) in m.data.iter_mut().enumerate() {
        if *id > 0 && in_block(i, w, h) {
            *id = *id % ids + 1;
            n += 1;
        }
    }
    stereo_io::write_id_png(&path, &m).unwrap();
    resign(data, &e.id, &MapKind::Instance.file_key("left"));
    n
}

#[test]
fn audit_checks_every_map_and_fails_corrupted_maps() {
    let tmp = tempfile::tempdir().unwrap();
    let clean = generate_with_maps(tmp.path(), "clean");

    // The generator's maps pass, in every category of the default preset.
    let (o, text) = audit(&clean);
    assert!(
        o.status.success(),
        "audit --check failed on correct maps:\n{text}"
    );
    assert!(text.contains("verdict: PASS"), "{text}");
    let report = audit_report(&clean);
    let mut cats: Vec<&str> = report["categories"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    cats.sort();
    assert_eq!(cats, ["hole", "reflective", "shapenet", "tree"]);
    for group in report["categories"].as_array().unwrap() {
        for kind in MapKind::ALL {
            let m = &group["maps"][kind.name()];
            let (pixels, checked) = (
                m["pixels"].as_u64().unwrap(),
                m["checked"].as_u64().unwrap(),
            );
            assert_eq!(
                pixels,
                2 * 64 * 48 * group["samples"].as_u64().unwrap(),
                "every pixel of both views: {}",
                group["name"]
            );
            // Nearly every pixel is checked, not set aside as a silhouette or crease.
            assert!(
                checked as f64 >= 0.85 * pixels as f64,
                "{} {kind}: {m}",
                group["name"]
            );
            assert!(
                m["share_in_bounds"].as_f64().unwrap() >= 0.9999,
                "{} {kind}: {m}",
                group["name"]
            );
            assert_eq!(m["validity_mismatch"], 0, "{} {kind}: {m}", group["name"]);
        }
    }
    let all = &report["overall"]["maps"];
    assert!(all["depth"]["max_error"].as_f64().unwrap() < 1e-4, "{all}");
    assert!(all["normals"]["max_error"].as_f64().unwrap() < 0.5, "{all}");

    // A copy with one map of three samples corrupted in a block of pixels.
    let data = tmp.path().join("corrupted");
    copy_dir(&clean, &data);
    let entries: Vec<ManifestEntry> = Manifest::read(&data.join("manifest.jsonl")).unwrap();
    let pick = |n: usize| {
        entries
            .iter()
            .filter(|e| e.instances.len() >= 2)
            .nth(n)
            .expect("scenes of several objects")
    };
    let (deep, flipped, swapped) = (pick(0), pick(1), pick(2));
    assert!(scale_depth(&data, deep) > 100);
    assert!(flip_normals(&data, flipped) > 100);
    assert!(swap_instances(&data, swapped) > 100);

    let (o, text) = audit(&data);
    assert!(
        !o.status.success(),
        "audit --check passed corrupted maps:\n{text}"
    );
    assert!(text.contains("verdict: FAIL"), "{text}");
    let fail_line = |id: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("FAIL sample {id} ")))
            .unwrap_or_else(|| panic!("no FAIL line for {id}:\n{text}"))
            .to_string()
    };
    for (e, map) in [(deep, "depth"), (flipped, "normals"), (swapped, "instance")] {
        let line = fail_line(&e.id);
        assert!(
            line.contains(&format!("{map}: ")) && line.contains("out of bounds"),
            "{line}"
        );
    }
    let report = audit_report(&data);
    let samples = audit_samples_by_id(&report);
    // Each corrupted sample fails on its corrupted map alone: the disparity and the other maps
    // (the semantic map of the swapped ids included) still pass, and no checksum differs.
    for (e, map) in [(deep, "depth"), (flipped, "normals"), (swapped, "instance")] {
        let s = &samples[&e.id];
        assert_eq!(s["checksum_mismatches"].as_array().unwrap().len(), 0, "{s}");
        assert!(
            !fail_line(&e.id).contains("0.01 px"),
            "the disparity is untouched"
        );
        for kind in MapKind::ALL {
            let m = &s["maps"][kind.name()];
            let off = m["checked"].as_u64().unwrap() - m["in_bounds"].as_u64().unwrap();
            if kind.name() == map {
                assert!(off > 50, "{} {map}: {m}", e.id);
            } else {
                assert_eq!(off, 0, "{} {kind}: {m}", e.id);
            }
        }
    }
    // The worst depth pixel is 1% off.
    let worst = report["map_worst"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["map"] == "depth")
        .unwrap();
    assert!(
        (worst["error"].as_f64().unwrap() - 0.01).abs() < 1e-4,
        "{worst}"
    );
    let flipped_worst = report["map_worst"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["map"] == "normals")
        .unwrap();
    assert!(
        flipped_worst["error"].as_f64().unwrap() > 179.0,
        "{flipped_worst}"
    );
    for e in &entries {
        if ![&deep.id, &flipped.id, &swapped.id].contains(&&e.id) {
            assert_eq!(
                samples[&e.id]["pass"], true,
                "untouched sample {}: {}",
                e.id, samples[&e.id]
            );
        }
    }
    for g in report["categories"].as_array().unwrap() {
        let bad = [deep, flipped, swapped]
            .iter()
            .any(|e| e.category == g["name"].as_str().unwrap());
        assert_eq!(g["pass"], !bad, "{}", g["name"]);
    }
}
