//! `stereogen stats --check` on a dataset the real generator rendered with real Blender: 24 scenes
//! of the tiny `crestereo` mix (64×48, disparity law uniform [3, 20] px, 2–3 objects per scene,
//! four categories). Its numbers are recounted here from the files, and the same rendered data
//! must fail the check once its dataset.json claims a law it was not drawn from.

use std::path::{Path, PathBuf};
use std::process::Output;
use test_support::{run_shown, stats_cmd};

use serde_json::Value;
use stereogen::dataset::{DatasetInfo, Manifest};
use stereogen::plan::Dist;

const SCENES: u64 = 24;

fn generate(dir: &Path) -> PathBuf {
    test_support::generate_tiny_dataset(dir, "data", SCENES, 3)
}

fn stats(data: &Path, out: &Path) -> (Output, String) {
    run_shown(
        stats_cmd(data)
            .args(["--check", "--plot", "--out"])
            .arg(out),
    )
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn stats_check_passes_on_a_generated_mixed_dataset_and_fails_when_the_law_is_misstated() {
    let tmp = tempfile::tempdir().unwrap();
    let data = generate(tmp.path());
    let out = tmp.path().join("stats");
    let (o, text) = stats(&data, &out);
    assert!(
        o.status.success(),
        "stats --check failed on a correct dataset:\n{text}"
    );
    assert!(text.contains("verdict: PASS"), "{text}");

    // Recount everything from the files the generator wrote.
    let entries = Manifest::read(&data.join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len() as u64, SCENES);
    let mut targets = Vec::new();
    let mut valid_values: Vec<f64> = Vec::new();
    let mut pixels = 0u64;
    for e in &entries {
        let spec = stereogen::dataset::read_scene_spec(&data.join(&e.files.scene)).unwrap();
        targets.extend(spec.target_disparities());
        for rel in [&e.files.disp_left, &e.files.disp_right] {
            let (m, _) = stereo_io::read_disparity_exr(&data.join(rel)).unwrap();
            pixels += m.data.len() as u64;
            valid_values.extend(
                m.data
                    .iter()
                    .zip(&m.valid)
                    .filter(|(_, v)| **v)
                    .map(|(d, _)| f64::from(*d)),
            );
        }
    }
    valid_values.sort_by(f64::total_cmp);
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    let all = &report["overall"];
    assert_eq!(report["samples"], SCENES);
    assert_eq!(all["objects"]["count"], targets.len());
    assert_eq!(all["pixels"]["pixels"], pixels);
    assert_eq!(all["pixels"]["valid"], valid_values.len());
    let cat_samples: u64 = report["categories"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["samples"].as_u64().unwrap())
        .sum();
    assert_eq!(cat_samples, SCENES);
    // Streaming percentiles agree with the exact ones within two fine bins.
    let fine_bin = f(&report["pixel_range"][1]) / 16384.0;
    let exact_median = valid_values[valid_values.len() / 2];
    let median = f(&all["pixels"]["percentiles"]["p50"]);
    assert!(
        (median - exact_median).abs() <= 2.0 * fine_bin + 1e-6,
        "median {median} vs exact {exact_median}"
    );
    // KS distance recomputed independently of the stats module.
    let law = Dist::uniform(3.0, 20.0);
    let ks = stereogen::plan::dist::ks_distance(&targets, &law);
    assert!((f(&all["objects"]["ks_distance"]) - ks).abs() < 1e-12);
    // The sample is large enough for a meaningful gap check: 48-72 objects allow 7-10 bins.
    let gap = &all["pixels"]["gap_check"];
    assert!(gap["bins"].as_u64().unwrap() >= 6, "{gap}");
    assert_eq!(gap["empty"].as_array().unwrap().len(), 0);
    // Every category line says OK (or SKIP when the 24 draws missed it).
    for line in text
        .lines()
        .filter(|l| l.starts_with("OK") || l.starts_with("FAIL") || l.starts_with("SKIP"))
    {
        assert!(!line.starts_with("FAIL"), "{line}");
    }
    for name in [
        "stats_objects.png",
        "stats_pixels.png",
        "stats_categories.png",
        "stats_coverage.png",
    ] {
        let img = stereo_io::read_rgb(&out.join(name)).unwrap();
        assert!(img.width >= 1000 && img.height >= 600, "{name}");
        assert!(img.data.iter().any(|&b| b < 128), "{name} is blank");
    }

    // The same pixels against a law they were not drawn from: the dataset claims [3, 50] px (still a valid
    // recipe at 64 px width), while no object was aimed beyond 20 px.
    let info_path = data.join("dataset.json");
    let mut info: DatasetInfo =
        serde_json::from_str(&std::fs::read_to_string(&info_path).unwrap()).unwrap();
    info.recipe.placement.disparity_px = Dist::uniform(3.0, 50.0);
    std::fs::write(&info_path, serde_json::to_string_pretty(&info).unwrap()).unwrap();
    let (o, text) = stats(&data, &tmp.path().join("stats-wrong"));
    assert!(
        !o.status.success(),
        "stats --check passed against a misstated law:\n{text}"
    );
    assert!(text.contains("verdict: FAIL"), "{text}");
    let all_line = text.lines().find(|l| l.contains(" all ")).unwrap();
    assert!(
        all_line.starts_with("FAIL") && all_line.contains("KS") && all_line.contains("gap:"),
        "{all_line}"
    );
}
