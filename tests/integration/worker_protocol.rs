//! The worker boundary with the real Blender worker: a worker whose scripts read another SceneSpec
//! version is refused once, at start-up, with both versions named; a scene that raises in Blender
//! lands in `failures.jsonl` with its Python traceback; rendered samples carry the worker's timings.

use std::path::Path;

use stereogen::dataset::Manifest;
use stereogen::plan::spec::SPEC_FORMAT_VERSION;
use stereogen::render::{Worker, WorkerError};
use test_support::{generate_cmd, worker_config, write_tiny_recipe};

#[test]
fn a_worker_that_reads_another_spec_version_is_refused_at_start() {
    let cfg = worker_config();
    // A copy of the installed scripts that claims another version.
    let dir = tempfile::tempdir().unwrap();
    let installed = cfg.script.parent().unwrap();
    for entry in std::fs::read_dir(installed).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, dir.path().join(path.file_name().unwrap())).unwrap();
    }
    let worker_py = dir.path().join("worker.py");
    let text = std::fs::read_to_string(&worker_py).unwrap();
    let stated = format!("SPEC_FORMAT_VERSION = {SPEC_FORMAT_VERSION}\n");
    assert!(
        text.contains(&stated),
        "worker.py states its version as {stated:?}"
    );
    std::fs::write(
        &worker_py,
        text.replace(&stated, "SPEC_FORMAT_VERSION = 2\n"),
    )
    .unwrap();

    let mut old = cfg.clone();
    old.script = worker_py;
    let err = Worker::spawn(&old)
        .err()
        .expect("a worker of another spec version is refused");
    assert!(
        matches!(
            err,
            WorkerError::SpecVersion {
                worker: Some(2),
                ..
            }
        ),
        "{err:?}"
    );
    assert!(err.is_fatal());
    let message = err.to_string();
    assert!(
        message.contains("SceneSpec version 2")
            && message.contains(&format!("writes version {SPEC_FORMAT_VERSION}")),
        "{message}"
    );
    assert!(!message.contains('\n'), "{message}");
    // The scripts the binary installs agree with it.
    Worker::spawn(&cfg)
        .expect("the installed worker starts")
        .shutdown();
}

fn generate(recipe: &Path, out: &Path, fault: &str) -> std::process::Output {
    generate_cmd(recipe, out, 3)
        .args(["--seed", "3"])
        .env("STEREOGEN_FAULT", fault)
        .output()
        .expect("run stereogen")
}

#[test]
fn a_scene_that_raises_in_blender_is_recorded_with_its_traceback() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("data");
    let o = generate(&recipe, &out, "raise@1");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("1 failed, 0 worker restart(s)"),
        "a scene error does not restart the worker: {err}"
    );

    let failures = std::fs::read_to_string(out.join("failures.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = failures
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 1, "{failures}");
    assert_eq!(lines[0]["index"], 1);
    assert!(
        lines[0]["error"]
            .as_str()
            .unwrap()
            .contains("RuntimeError: injected failure"),
        "{failures}"
    );
    let traceback = lines[0]["traceback"]
        .as_str()
        .expect("the traceback is kept");
    assert!(
        traceback.starts_with("Traceback (most recent call last)")
            && traceback.contains("worker.py"),
        "{traceback}"
    );

    let entries = Manifest::read(&out.join("manifest.jsonl")).unwrap();
    let mut done: Vec<u64> = entries.iter().map(|e| e.index).collect();
    done.sort();
    assert_eq!(done, [0, 2]);
    for e in &entries {
        let worker_seconds: f64 = e.render_timings.values().sum();
        assert!(
            e.render_timings.contains_key("build_s") && e.render_timings.contains_key("save_s"),
            "{:?}",
            e.render_timings
        );
        assert!(
            worker_seconds > 0.0 && worker_seconds <= e.render_seconds,
            "{:?} vs {} s",
            e.render_timings,
            e.render_seconds
        );
    }
}
