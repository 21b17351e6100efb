//! `stereogen stats --check` on hand-made datasets with known flaws: a real `DatasetInfo` with the
//! `crestereo` preset (law uniform [2, 240] px), SceneSpecs from the real planner with their
//! object targets set by the test, and disparity EXRs painted by the test (one disc per object,
//! bulging towards the camera by up to 8%, near objects painted last, top 4 rows invalid).
//!
//! - `Follows`: targets spread evenly over [2, 240], pixels at the targets: must pass.
//! - `GapEverywhere`: targets and pixels only in [2, 40] ∪ [150, 240]: KS and gap must both fail.
//! - `PixelGap`: targets follow the law, but every object aimed into (40, 150) is painted squeezed
//!   into [2, 40] (a renderer that ignores the plan): only the gap check can see it.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output};
use test_support::run_shown;

use serde_json::Value;
use stereo_io::{DisparityMap, DisparityMeta};
use stereogen::assets::AssetIndex;
use stereogen::dataset::{DatasetInfo, DatasetLayout, DisparitySummary, ManifestEntry};
use stereogen::plan::{ObjectRole, Recipe, plan_scene};
use stereogen::validate::hist::gap_bins_for;

const SCENES: u64 = 40;
const W: usize = 96;
const H: usize = 64;
const INVALID_ROWS: usize = 4;
const BACKGROUND: f32 = 1.0;
const RADIUS: f64 = 5.0;

#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Follows,
    GapEverywhere,
    PixelGap,
}

/// Low-discrepancy fractions (golden-ratio sequence): spread evenly, deterministic.
fn golden(j: u64) -> f64 {
    (0.5 + j as f64 * 0.618_033_988_749_895).fract()
}

fn target(mode: Mode, j: u64) -> f64 {
    let u = golden(j);
    match mode {
        Mode::Follows | Mode::PixelGap => 2.0 + 238.0 * u,
        Mode::GapEverywhere => {
            let x = u * 128.0; // 38 px of [2, 40] + 90 px of [150, 240]
            if x < 38.0 {
                2.0 + x
            } else {
                150.0 + (x - 38.0)
            }
        }
    }
}

fn painted(mode: Mode, t: f64) -> f64 {
    if mode == Mode::PixelGap && t > 40.0 && t < 150.0 {
        2.0 + (t - 40.0) / 110.0 * 38.0
    } else {
        t
    }
}

fn paint(discs: &[(f64, f64, f64)]) -> DisparityMap {
    let mut m = DisparityMap::new(W, H);
    for y in INVALID_ROWS..H {
        for x in 0..W {
            m.data[y * W + x] = BACKGROUND;
            m.valid[y * W + x] = true;
        }
    }
    let mut order: Vec<&(f64, f64, f64)> = discs.iter().collect();
    order.sort_by(|a, b| a.2.total_cmp(&b.2)); // far (small disparity) first
    for &&(cx, cy, d) in &order {
        for y in INVALID_ROWS..H {
            for x in 0..W {
                let r2 = ((x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2))
                    / (RADIUS * RADIUS);
                if r2 <= 1.0 {
                    m.data[y * W + x] = (d * (1.0 + 0.08 * (1.0 - r2))) as f32;
                }
            }
        }
    }
    m
}

/// Writes a dataset and returns the number of content objects per category.
fn make_dataset(root: &Path, mode: Mode) -> BTreeMap<String, usize> {
    let recipe = Recipe::preset("crestereo").unwrap();
    assert_eq!(
        recipe.placement.disparity_px,
        stereogen::plan::Dist::uniform(2.0, 240.0)
    );
    let layout = DatasetLayout::new(root);
    let info = DatasetInfo {
        stereogen_version: "test".into(),
        seed: 7,
        recipe_fingerprint: recipe.fingerprint(),
        recipe: recipe.clone(),
        assets_fingerprint: None,
        curation: Vec::new(),
        semantic_classes: Vec::new(),
    };
    std::fs::create_dir_all(root).unwrap();
    std::fs::write(layout.info(), serde_json::to_string_pretty(&info).unwrap()).unwrap();
    let assets = AssetIndex::default();
    let mut manifest = String::new();
    let mut objects = BTreeMap::new();
    let mut j = 0u64;
    for index in 0..SCENES {
        let category = recipe.categories[index as usize % recipe.categories.len()]
            .name
            .clone();
        let mut spec = plan_scene(&recipe, &assets, 7, index);
        spec.id = format!("{index:07}");
        spec.category = category.clone();
        let mut discs = Vec::new();
        for (k, o) in spec
            .objects
            .iter_mut()
            .filter(|o| o.role == ObjectRole::Content)
            .enumerate()
        {
            let t = target(mode, j);
            o.target_disparity = Some(t);
            let cx = RADIUS + golden(j * 7 + 3) * (W as f64 - 2.0 * RADIUS);
            let cy = INVALID_ROWS as f64
                + RADIUS
                + golden(j * 11 + k as u64) * (H as f64 - INVALID_ROWS as f64 - 2.0 * RADIUS);
            discs.push((cx, cy, painted(mode, t)));
            j += 1;
        }
        assert!(!discs.is_empty(), "the planner made no content objects");
        *objects.entry(category.clone()).or_insert(0) += discs.len();
        let files = layout.sample_paths(&category, &spec.id);
        std::fs::create_dir_all(root.join(&category)).unwrap();
        std::fs::write(root.join(&files.scene), spec.to_json()).unwrap();
        let left = paint(&discs);
        // The right view sees every disc shifted left by its disparity.
        let right = paint(
            &discs
                .iter()
                .map(|&(x, y, d)| (x - d * W as f64 / 960.0, y, d))
                .collect::<Vec<_>>(),
        );
        for (map, rel, view) in [
            (&left, &files.disp_left, "left"),
            (&right, &files.disp_right, "right"),
        ] {
            let meta = DisparityMeta {
                f_px: Some(500.0),
                baseline_m: Some(0.1),
                view: Some(view.into()),
            };
            stereo_io::write_disparity_exr(&root.join(rel), map, &meta).unwrap();
        }
        let entry = ManifestEntry {
            id: spec.id.clone(),
            category,
            seed: 7,
            index,
            files,
            width: W as u32,
            height: H as u32,
            f_px: 500.0,
            baseline_m: 0.1,
            cx: W as f64 / 2.0,
            cy: H as f64 / 2.0,
            disparity_left: DisparitySummary::of(&left),
            disparity_right: DisparitySummary::of(&right),
            difficulty: None,
            render_seconds: 0.0,
            render_timings: BTreeMap::new(),
            notes: Vec::new(),
            instances: Vec::new(),
            sha256: BTreeMap::new(),
            stereogen_version: "test".into(),
        };
        manifest += &serde_json::to_string(&entry).unwrap();
        manifest.push('\n');
    }
    std::fs::write(layout.manifest(), manifest).unwrap();
    objects
}

fn stats(root: &Path, extra: &[&str]) -> (Output, String, Value) {
    let out = root.join("stats-out");
    let (o, text) = run_shown(
        Command::new(env!("CARGO_BIN_EXE_stereogen"))
            .arg("stats")
            .arg(root)
            .arg("--out")
            .arg(&out)
            .args(extra),
    );
    let report =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    (o, text, report)
}

fn category_lines(text: &str) -> Vec<&str> {
    text.lines()
        .filter(|l| ["OK", "FAIL", "SKIP"].iter().any(|t| l.starts_with(t)))
        .collect()
}

#[test]
fn check_passes_on_a_hand_made_dataset_that_follows_the_law() {
    let tmp = tempfile::tempdir().unwrap();
    let objects = make_dataset(tmp.path(), Mode::Follows);
    let (o, text, report) = stats(tmp.path(), &["--check"]);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("verdict: PASS"), "{text}");
    let lines = category_lines(&text);
    assert_eq!(lines.len(), 5, "{text}");
    assert!(lines.iter().all(|l| l.starts_with("OK")), "{text}");
    // Numbers the test knows exactly.
    for c in report["categories"].as_array().unwrap() {
        let name = c["name"].as_str().unwrap();
        assert_eq!(c["samples"], SCENES / 4);
        assert_eq!(c["objects"]["count"], objects[name]);
        let p = &c["pixels"];
        assert_eq!(p["pixels"], SCENES / 4 * 2 * (W * H) as u64);
        assert_eq!(
            p["invalid_fraction"].as_f64().unwrap(),
            INVALID_ROWS as f64 / H as f64
        );
        assert_eq!(p["nonfinite_valid"], 0);
        // Bins by the documented rule; enough objects per category for a fine check.
        assert_eq!(p["gap_check"]["bins"], gap_bins_for(objects[name], 0.01));
        assert!(
            p["gap_check"]["bins"].as_u64().unwrap() >= 6,
            "{name}: {}",
            p["gap_check"]
        );
        // The invalid rows show up as a zero valid fraction in the first row band.
        assert_eq!(p["rows"][0]["valid_fraction"].as_f64().unwrap(), 0.0);
        assert_eq!(
            p["rows"][report["overall"]["pixels"]["rows"]
                .as_array()
                .unwrap()
                .len()
                - 1]["valid_fraction"]
                .as_f64()
                .unwrap(),
            1.0
        );
    }
    let all = &report["overall"];
    assert_eq!(all["objects"]["count"], objects.values().sum::<usize>());
    assert_eq!(
        all["pixels"]["gap_check"]["bins"],
        gap_bins_for(objects.values().sum(), 0.01)
    );
    assert!(all["pixels"]["gap_check"]["bins"].as_u64().unwrap() >= 40);
}

#[test]
fn check_fails_on_a_hand_made_dataset_with_a_gap() {
    let tmp = tempfile::tempdir().unwrap();
    make_dataset(tmp.path(), Mode::GapEverywhere);
    let (o, text, report) = stats(tmp.path(), &["--check"]);
    assert!(
        !o.status.success(),
        "stats --check passed a dataset with a gap:\n{text}"
    );
    assert!(text.contains("verdict: FAIL"), "{text}");
    for line in category_lines(&text) {
        assert!(
            line.starts_with("FAIL") && line.contains("object-level KS") && line.contains("gap:"),
            "{line}"
        );
    }
    // The empty bins are exactly the ones inside the gap: bins wholly inside (40·1.08, 150) are
    // empty, bins wholly inside [2, 40] or [150, 240] are not.
    for c in report["categories"]
        .as_array()
        .unwrap()
        .iter()
        .chain([&report["overall"]])
    {
        let g = &c["pixels"]["gap_check"];
        let edges: Vec<f64> = g["edges"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let counts: Vec<u64> = g["counts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect();
        let mut inside_gap = 0;
        for (i, &n) in counts.iter().enumerate() {
            let (a, b) = (edges[i], edges[i + 1]);
            if a >= 43.2 && b <= 150.0 {
                assert_eq!(n, 0, "{}: bin [{a}, {b}) should be empty", c["name"]);
                inside_gap += 1;
            }
            if b <= 40.0 || a >= 150.0 {
                assert!(n > 0, "{}: bin [{a}, {b}) should not be empty", c["name"]);
            }
        }
        assert!(inside_gap >= 1);
        assert_eq!(
            g["empty"].as_array().unwrap().len(),
            counts.iter().filter(|n| **n == 0).count()
        );
    }
}

#[test]
fn check_sees_a_pixel_gap_even_when_object_targets_follow_the_law() {
    let tmp = tempfile::tempdir().unwrap();
    make_dataset(tmp.path(), Mode::PixelGap);
    let (o, text, _) = stats(tmp.path(), &["--check"]);
    assert!(!o.status.success(), "{text}");
    for line in category_lines(&text) {
        assert!(
            line.starts_with("FAIL") && line.contains("gap:") && !line.contains("object-level KS"),
            "{line}"
        );
    }
    // With only two gap bins ([2, 121] and [121, 240]) the hole is too coarse to see: the check
    // passes. The bin count is what gives the check its resolution.
    let (o, text, report) = stats(tmp.path(), &["--check", "--gap-bins", "2"]);
    assert!(o.status.success(), "{text}");
    assert_eq!(report["overall"]["pixels"]["gap_check"]["bins"], 2);
}

#[test]
fn unreadable_maps_and_plots() {
    let tmp = tempfile::tempdir().unwrap();
    make_dataset(tmp.path(), Mode::Follows);
    // Plots render text and curves (not blank) at the documented sizes.
    let (o, text, _) = stats(tmp.path(), &["--plot", "--bins", "48"]);
    assert!(o.status.success(), "{text}");
    for (name, w) in [
        ("stats_objects.png", 1000),
        ("stats_pixels.png", 1000),
        ("stats_categories.png", 1400),
        ("stats_coverage.png", 1400),
    ] {
        let img = stereo_io::read_rgb(&tmp.path().join("stats-out").join(name)).unwrap();
        assert_eq!(img.width, w, "{name}");
        let dark = img
            .data
            .chunks(3)
            .filter(|p| p.iter().all(|&c| c < 80))
            .count();
        assert!(
            dark > 2000,
            "{name}: only {dark} dark pixels (no text or axes?)"
        );
    }
    // A missing EXR is reported and fails the check.
    let victim = tmp.path().join("tree").join("0000001_right.disp.exr");
    std::fs::remove_file(&victim).unwrap();
    let (o, text, report) = stats(tmp.path(), &["--check"]);
    assert!(!o.status.success(), "{text}");
    assert!(
        text.contains("ERROR") && text.contains("0000001_right.disp.exr"),
        "{text}"
    );
    assert!(
        text.contains("verdict: FAIL (1 unreadable file(s))"),
        "{text}"
    );
    assert_eq!(report["errors"].as_array().unwrap().len(), 1);
    assert_eq!(text.matches("0000001_right.disp.exr").count(), 1, "{text}");
}

#[test]
fn a_manifest_line_being_appended_is_left_out() {
    let tmp = tempfile::tempdir().unwrap();
    make_dataset(tmp.path(), Mode::Follows);
    let path = tmp.path().join("manifest.jsonl");
    let text = std::fs::read_to_string(&path).unwrap();
    // Cut the last line in half, as a reader racing `generate`'s append would see it.
    let cut = text.len() - text.lines().last().unwrap().len() / 2 - 1;
    std::fs::write(&path, &text[..cut]).unwrap();
    let (o, text, report) = stats(tmp.path(), &["--check"]);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("ignoring an unfinished last line"), "{text}");
    assert_eq!(report["samples"], SCENES - 1);
}

#[test]
fn an_empty_dataset_does_not_pass() {
    let tmp = tempfile::tempdir().unwrap();
    make_dataset(tmp.path(), Mode::Follows);
    std::fs::write(tmp.path().join("manifest.jsonl"), "").unwrap();
    let (o, text, report) = stats(tmp.path(), &["--check"]);
    assert!(!o.status.success(), "{text}");
    assert!(
        text.contains("verdict: FAIL (the dataset has no samples)"),
        "{text}"
    );
    assert_eq!(report["samples"], 0);
    assert!(
        category_lines(&text).iter().all(|l| l.starts_with("SKIP")),
        "{text}"
    );
}
