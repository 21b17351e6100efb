//! The smaller findings of the fault sweep, through the real CLI: arguments refused before any
//! work, `failures.jsonl` kept to the samples still missing, and a broken file never looking
//! like success.

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use test_support::{generate_cmd, stereogen_cmd, write_tiny_recipe};

fn stereogen<S: AsRef<std::ffi::OsStr>>(args: &[S], dir: &Path) -> Output {
    stereogen_cmd(args)
        .current_dir(dir)
        .output()
        .expect("run stereogen")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Fails at once (no Blender started) with one line naming `expect`.
fn assert_refused_at_once(mut c: Command, dir: &Path, expect: &str) {
    let args: Vec<_> = c.get_args().map(|a| a.to_os_string()).collect();
    let t0 = Instant::now();
    let o = c.current_dir(dir).output().expect("run stereogen");
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} was accepted: {err}");
    assert!(err.contains(expect), "expected {expect:?} in: {err}");
    assert!(
        t0.elapsed() < Duration::from_secs(10),
        "{args:?} was refused only after {:?}",
        t0.elapsed()
    );
}

#[test]
fn impossible_arguments_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let generate = |count: u64, extra: &[&str]| {
        let mut c = generate_cmd(&recipe, Path::new("data"), count);
        c.args(extra);
        c
    };
    assert_refused_at_once(
        generate(3, &["--start", "18446744073709551613"]),
        dir.path(),
        "the range ends past the largest index",
    );
    assert_refused_at_once(generate(1, &["--timeout", "0"]), dir.path(), "--timeout");

    let spec = stereogen(&["plan", "--seed", "1", "--index", "0"], dir.path());
    assert!(spec.status.success());
    let spec: serde_json::Value = serde_json::from_slice(&spec.stdout).unwrap();
    for (key, value, named) in [
        ("width", serde_json::json!(0), "rig.width"),
        ("baseline_m", serde_json::json!(1e308), "rig.baseline_m"),
    ] {
        let mut bad = spec.clone();
        bad["rig"][key] = value;
        bad.as_object_mut().unwrap().remove("cameras");
        std::fs::write(dir.path().join("bad.json"), bad.to_string()).unwrap();
        assert_refused_at_once(
            stereogen_cmd(["render", "--spec", "bad.json", "--out", "one"]),
            dir.path(),
            named,
        );
        assert!(
            !dir.path().join("one").exists(),
            "a refused spec created its output folder"
        );
    }
}

#[test]
fn failures_are_forgotten_once_rendered_and_broken_files_fail_stats() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let generate = |fault: Option<&str>| {
        let mut c = generate_cmd(&recipe, Path::new("data"), 3);
        c.args(["--seed", "4", "--retries", "0"])
            .current_dir(dir.path());
        if let Some(f) = fault {
            c.env("STEREOGEN_FAULT", f);
        }
        c.output().unwrap()
    };
    let o = generate(Some("crash-always@1"));
    assert!(!o.status.success());
    let failures = dir.path().join("data/failures.jsonl");
    assert!(
        std::fs::read_to_string(&failures)
            .unwrap()
            .contains("\"index\":1")
    );
    let o = generate(None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        !failures.exists(),
        "failures.jsonl still lists a sample the re-run rendered: {}",
        std::fs::read_to_string(&failures).unwrap_or_default()
    );

    let data = dir.path().join("data");
    let entries = stereogen::dataset::Manifest::read(&data.join("manifest.jsonl")).unwrap();
    assert!(
        stereogen(&["stats", "data", "--verify"], dir.path())
            .status
            .success()
    );
    // A PNG changed behind the manifest's back: only a verification reads it.
    let png = data.join(&entries[0].files.left);
    let mut bytes = std::fs::read(&png).unwrap();
    let n = bytes.len();
    bytes[n - 20] ^= 0x55;
    std::fs::write(&png, &bytes).unwrap();
    let o = stereogen(&["stats", "data", "--verify"], dir.path());
    let said = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
    assert!(
        !o.status.success()
            && said.contains(&*entries[0].files.left.to_string_lossy())
            && said.contains("differs from the manifest"),
        "stats --verify: {said}"
    );
    // A cut disparity EXR fails `stats` even without --check.
    let exr = data.join(&entries[1].files.disp_left);
    let bytes = std::fs::read(&exr).unwrap();
    std::fs::write(&exr, &bytes[..bytes.len() / 2]).unwrap();
    let o = stereogen(&["stats", "data"], dir.path());
    assert!(
        !o.status.success(),
        "stats exited 0 on an unreadable file: {}",
        stderr(&o)
    );
    assert!(stderr(&o).contains("unreadable"), "{}", stderr(&o));
}

/// `plan` prints a scene as JSON on stdout, and only that, even when it must first install the
/// content pack into a fresh home (pip's report once landed on stdout there).
#[test]
fn plan_stdout_is_only_the_scene_while_the_pack_installs() {
    let dir = tempfile::tempdir().unwrap();
    let o = stereogen_cmd(["plan", "--seed", "3", "--index", "2"])
        .current_dir(dir.path())
        .env("STEREOGEN_HOME", dir.path().join("fresh-home"))
        .output()
        .expect("run stereogen");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("downloading the content pack"),
        "the fresh home did not install the pack: {}",
        stderr(&o)
    );
    let spec: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!(
            "plan's stdout is not one JSON scene ({e}): {}",
            String::from_utf8_lossy(&o.stdout)
        )
    });
    assert_eq!(spec["index"], 2);
}
