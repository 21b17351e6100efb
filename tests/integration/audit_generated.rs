//! `stereogen audit --check` on datasets the real generator rendered with real Blender: it passes
//! on tiny datasets of every preset (every pixel of every sample), and on a copy whose ground
//! truth is corrupted in the ways a broken pipeline would corrupt it it fails and names each
//! corrupted sample with the reason, while the untouched samples still pass.

use std::path::{Path, PathBuf};
use std::process::Output;
use test_support::files::copy_dir;
use test_support::{audit_cmd, audit_report, audit_samples_by_id, resign, run_shown};

use stereo_io::DisparityMap;
use stereogen::dataset::{DatasetLayout, Manifest, ManifestEntry};
use stereogen::plan::recipe::PRESETS;

/// With seed 3 the first 8 scenes of the tiny `crestereo` mix cover all four categories.
const MIX_SCENES: u64 = 8;
const MIX_SEED: u64 = 3;

fn generate(dir: &Path, preset: &str, count: u64, seed: u64) -> PathBuf {
    test_support::generate_tiny_preset(dir, preset, preset, count, seed)
}

fn audit(data: &Path, extra: &[&str]) -> (Output, String) {
    run_shown(
        audit_cmd(data)
            .args(["--all", "--every-pixel", "--check"])
            .args(extra),
    )
}

fn read_map(path: &Path) -> (DisparityMap, stereo_io::DisparityMeta) {
    stereo_io::read_disparity_exr(path).unwrap()
}

/// Adds 0.05 px to every pixel of the nearest object (the valid pixels above the median of the
/// content range): a ground truth slightly off on one object.
fn shift_object(path: &Path) -> usize {
    let (mut map, meta) = read_map(path);
    let max = map
        .data
        .iter()
        .zip(&map.valid)
        .filter(|(_, v)| **v)
        .map(|(d, _)| *d)
        .fold(0.0f32, f32::max);
    let threshold = 0.5 * (max + 3.0);
    let mut n = 0;
    for (d, v) in map.data.iter_mut().zip(&map.valid) {
        if *v && *d >= threshold {
            *d += 0.05;
            n += 1;
        }
    }
    stereo_io::write_disparity_exr(path, &map, &meta).unwrap();
    n
}

/// Replaces each pixel left of a depth edge (a jump of more than 2 px along the row) by the mean
/// of the two sides, as a depth map filtered across an edge would hold.
fn blur_edges(path: &Path) -> usize {
    let (mut map, meta) = read_map(path);
    let (w, h) = (map.width, map.height);
    let mut n = 0;
    for y in 0..h {
        for x in 0..w - 1 {
            let (i, j) = (y * w + x, y * w + x + 1);
            if map.valid[i] && map.valid[j] && (map.data[i] - map.data[j]).abs() > 2.0 && n < 12 {
                map.data[i] = 0.5 * (map.data[i] + map.data[j]);
                n += 1;
            }
        }
    }
    stereo_io::write_disparity_exr(path, &map, &meta).unwrap();
    n
}

#[test]
fn audit_check_passes_on_every_preset() {
    let tmp = tempfile::tempdir().unwrap();
    for (preset, _) in PRESETS {
        let (count, seed) = if *preset == "crestereo" {
            (MIX_SCENES, MIX_SEED)
        } else {
            (1, 1)
        };
        let data = generate(tmp.path(), preset, count, seed);
        let (o, text) = audit(&data, &[]);
        assert!(
            o.status.success(),
            "audit --check failed on a correct {preset} dataset:\n{text}"
        );
        assert!(text.contains("verdict: PASS"), "{text}");
        let report = audit_report(&data);
        let entries = Manifest::read(&data.join("manifest.jsonl")).unwrap();
        assert_eq!(report["samples"].as_array().unwrap().len(), entries.len());
        // Every pixel of both views was audited, and nearly all of them are interior pixels.
        let all = &report["overall"]["tally"];
        assert_eq!(
            all["pixels"].as_u64().unwrap(),
            2 * 64 * 48 * entries.len() as u64
        );
        assert!(
            all["interior"].as_u64().unwrap() as f64 >= 0.85 * all["pixels"].as_f64().unwrap(),
            "{all}"
        );
        assert_eq!(all["flying"], 0);
        assert!(all["max_error"].as_f64().unwrap() < 0.01, "{all}");
        if *preset == "crestereo" {
            let mut cats: Vec<&str> = report["categories"]
                .as_array()
                .unwrap()
                .iter()
                .map(|c| c["name"].as_str().unwrap())
                .collect();
            cats.sort();
            assert_eq!(
                cats,
                ["hole", "reflective", "shapenet", "tree"],
                "the mix covers every category"
            );
        }
    }
}

#[test]
fn audit_check_fails_on_corrupted_ground_truth_and_names_the_samples() {
    let tmp = tempfile::tempdir().unwrap();
    let clean = generate(tmp.path(), "crestereo", MIX_SCENES, MIX_SEED);
    let data = tmp.path().join("corrupted");
    copy_dir(&clean, &data);
    let layout = DatasetLayout::new(&data);
    let entries: Vec<ManifestEntry> = Manifest::read(&layout.manifest()).unwrap();
    let [shifted, blurred, swapped, edited, unreadable, no_scene, ..] = &entries[..] else {
        panic!("8 samples")
    };

    assert!(shift_object(&layout.abs(&shifted.files.disp_left)) > 20);
    resign(&data, &shifted.id, "disp_left");
    assert!(blur_edges(&layout.abs(&blurred.files.disp_right)) > 0);
    resign(&data, &blurred.id, "disp_right");
    let (l, r) = (
        layout.abs(&swapped.files.disp_left),
        layout.abs(&swapped.files.disp_right),
    );
    let tmp_swap = data.join("swap.exr");
    std::fs::rename(&l, &tmp_swap).unwrap();
    std::fs::rename(&r, &l).unwrap();
    std::fs::rename(&tmp_swap, &r).unwrap();
    resign(&data, &swapped.id, "disp_left");
    resign(&data, &swapped.id, "disp_right");
    // An image edited after the manifest was written: only its checksum can tell.
    let png = layout.abs(&edited.files.left);
    let mut bytes = std::fs::read(&png).unwrap();
    bytes.extend(b"edited");
    std::fs::write(&png, bytes).unwrap();
    let exr = layout.abs(&unreadable.files.disp_right);
    std::fs::write(&exr, b"not an exr").unwrap();
    resign(&data, &unreadable.id, "disp_right");
    std::fs::remove_file(layout.abs(&no_scene.files.scene)).unwrap();
    // A run still appending: its unfinished last line is left out, with a note.
    std::fs::OpenOptions::new()
        .append(true)
        .open(layout.manifest())
        .and_then(|mut f| std::io::Write::write_all(&mut f, b"{\"id\":\"000"))
        .unwrap();

    let (o, text) = audit(&data, &[]);
    assert!(
        !o.status.success(),
        "audit --check passed a corrupted dataset:\n{text}"
    );
    assert!(text.contains("verdict: FAIL"), "{text}");
    assert!(text.contains("unfinished last line was left out"), "{text}");
    let fail_line = |id: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("FAIL sample {id} ")))
            .unwrap_or_else(|| panic!("no FAIL line for {id}:\n{text}"))
            .to_string()
    };
    // Each damaged sample's FAIL line names what is wrong with it.
    let assert_fail_says = |id: &str, needles: &[&str]| {
        let line = fail_line(id);
        assert!(needles.iter().all(|n| line.contains(n)), "{line}");
    };
    assert_fail_says(&shifted.id, &["off by more than 0.01 px"]);
    assert_fail_says(&blurred.id, &["flying pixel"]);
    assert_fail_says(&swapped.id, &["off by more than 0.01 px"]);
    assert_fail_says(&edited.id, &["left", "changed since the manifest"]);
    assert_fail_says(&unreadable.id, &[&*exr.to_string_lossy()]);
    assert_fail_says(&no_scene.id, &["scene.json"]);

    let report = audit_report(&data);
    let samples = audit_samples_by_id(&report);
    for e in &entries[6..] {
        assert_eq!(
            samples[&e.id]["pass"], true,
            "untouched sample {} fails: {}",
            e.id, samples[&e.id]
        );
    }
    // The shifted object's pixels are off by 0.05 px, and reported as the worst.
    let worst = &samples[&shifted.id]["worst"][0];
    assert!(
        (worst["error"].as_f64().unwrap() - 0.05).abs() < 1e-3,
        "{worst}"
    );
    assert_eq!(worst["view"], "left");
    assert_eq!(report["overall"]["checksum_mismatches"], 1);
    assert_eq!(report["unfinished_manifest_line"], true);
    assert_eq!(report["manifest_samples"], MIX_SCENES);
    assert!(samples[&blurred.id]["tally"]["flying"].as_u64().unwrap() > 0);
}

#[test]
fn audit_explains_datasets_it_cannot_audit() {
    let tmp = tempfile::tempdir().unwrap();
    // An empty dataset: the generator made its directory, then every sample failed.
    let data = test_support::generate_failed_dataset(tmp.path(), "only-failures");
    let (o, text) = audit(&data, &[]);
    assert!(!o.status.success());
    assert!(
        text.contains("no finished samples")
            && text.contains("1 sample(s) failed")
            && text.contains("failures.jsonl"),
        "{text}"
    );
    std::fs::remove_file(data.join("failures.jsonl")).unwrap();
    let (o, text) = audit(&data, &[]);
    assert!(
        !o.status.success() && text.contains("no finished samples"),
        "{text}"
    );
    let (o, text) = audit(&tmp.path().join("nowhere"), &[]);
    assert!(!o.status.success() && text.contains("nowhere"), "{text}");
}
