//! `stereogen estimate` with the real Blender worker: it renders a few of the dataset's own
//! planned samples (spread over the categories) through `generate` in a temporary folder under
//! `--work`, removes it, and prints the projection as a table and as JSON.

use std::path::Path;
use std::process::Output;

use stereogen::plan::{Recipe, scene_category};
use test_support::{output_text as text, stereogen_cmd, tiny_recipe, write_tiny_recipe};

fn estimate(recipe: &Path, work: &Path, count: u64, extra: &[&str]) -> Output {
    let o = stereogen_cmd(["estimate", "--threads", "1", "--seed", "7"])
        .arg("--recipe")
        .arg(recipe)
        .args(["--count", &count.to_string(), "--work"])
        .arg(work)
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "estimate: {}", text(&o));
    o
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn estimate_renders_samples_of_every_category_and_projects_them() {
    let dir = tempfile::tempdir().unwrap();
    let recipe_path = write_tiny_recipe(dir.path(), "crestereo");
    let recipe: Recipe = tiny_recipe("crestereo");
    let work = dir.path().join("work");
    let count = 1000;
    let o = estimate(&recipe_path, &work, count, &["--sample", "4", "--json"]);
    let e: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON on stdout");
    assert_eq!(
        std::fs::read_dir(&work).unwrap().count(),
        0,
        "the temporary dataset is removed from --work"
    );

    // Four samples of the dataset itself (seed 7, 0..1000), one per category.
    let samples = e["measured"]["samples"].as_array().unwrap();
    assert_eq!(samples.len(), 4, "{e:#}");
    for s in samples {
        let index = s["index"].as_u64().unwrap();
        assert!(index < count);
        assert_eq!(
            s["category"].as_str().unwrap(),
            scene_category(&recipe, 7, index).name,
            "sample {index} is the dataset's own"
        );
        let seconds = f(&s["seconds"]);
        assert!(
            seconds > 0.05 && seconds < 120.0,
            "a tiny sample in {seconds} s"
        );
        assert!(f(&s["parallel_seconds"]) <= seconds);
        assert_eq!(s["files"], 5, "images, disparities, scene");
        assert!(s["bytes"].as_u64().unwrap() > 1000);
    }
    let starts = e["measured"]["worker_start_s"].as_array().unwrap();
    assert_eq!(starts.len(), 1, "one worker, one start-up");
    assert!(
        f(&starts[0]) > 0.1,
        "Blender's start-up is measured apart: {e:#}"
    );
    assert!(f(&e["measured"]["task_fixed_s"]) >= f(&starts[0]));

    // Categories: the range's exact counts, each measured once; the totals add up.
    let cats = e["categories"].as_array().unwrap();
    assert_eq!(cats.len(), recipe.categories.len());
    let mut n = 0;
    let mut hours = 0.0;
    let mut bytes = 0;
    for (c, r) in cats.iter().zip(&recipe.categories) {
        assert_eq!(c["name"], r.name.as_str());
        assert_eq!(c["measured"], 1);
        let want = (0..count)
            .filter(|&i| scene_category(&recipe, 7, i).name == r.name)
            .count() as u64;
        assert_eq!(c["samples"].as_u64().unwrap(), want, "{}", r.name);
        // One thread here and in the projection: core-seconds = the measured wall seconds.
        let ds = f(&c["device_seconds"]["mean"]);
        assert!((ds - f(&c["seconds"]["mean"])).abs() < 1e-9);
        assert!((f(&c["hours"]) - want as f64 * ds / 3600.0).abs() < 1e-9);
        assert!(f(&c["hours_sem"]) > 0.0, "a spread from the pooled samples");
        n += want;
        hours += f(&c["hours"]);
        bytes += c["bytes"].as_u64().unwrap();
    }
    assert_eq!(n, count);
    assert!((f(&e["sample_hours"]) - hours).abs() < 1e-9);
    assert!(
        f(&e["hours"]) > f(&e["sample_hours"]),
        "plus the task's start-up"
    );
    assert_eq!(e["unit"], "core-hours");
    let dataset_files = e["measured"]["dataset_files"].as_u64().unwrap();
    assert_eq!(dataset_files, 2, "dataset.json and manifest.jsonl");
    assert_eq!(e["files"].as_u64().unwrap(), 5 * count + dataset_files);
    assert!(e["bytes"].as_u64().unwrap() > bytes);
    let spread = &e["seconds"];
    assert!(f(&spread["min"]) <= f(&spread["median"]) && f(&spread["median"]) <= f(&spread["max"]));
    let task = &e["task"];
    assert_eq!(task["samples"], count);
    let wall = f(&task["wall_s"]);
    assert!(
        (wall - f(&task["fixed_s"]) - 3600.0 * f(&e["sample_hours"])).abs() < 1e-6,
        "one task of one 1-core worker: its wall time is the samples' plus its fixed time"
    );

    // The table, split over 4 tasks.
    let o = estimate(
        &recipe_path,
        &work,
        count,
        &["--sample", "4", "--tasks", "4"],
    );
    let table = String::from_utf8_lossy(&o.stdout);
    for want in [
        "estimate of 1000 samples of crestereo (64×48 px, 2 samples per pixel), seed 7",
        "worker start-up",
        "core-hours",
        "largest task: 250 samples",
        "s/sample min/med/max",
    ] {
        assert!(table.contains(want), "no {want:?} in:\n{table}");
    }
    for c in &recipe.categories {
        assert!(
            table.lines().any(|l| l.starts_with(c.name.as_str())),
            "{table}"
        );
    }
    assert!(table.lines().any(|l| l.starts_with("total")), "{table}");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0);
}
