//! The real `stereogen` CLI with the real Blender worker: resume after SIGKILL, fault recovery,
//! and one-line errors for bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use stereogen::dataset::{DatasetLayout, Manifest};
use stereogen::plan::recipe::PRESETS;
use test_support::files::write_replaced;
use test_support::{assert_listed_file_intact, stereogen_cmd, write_tiny_recipe};

/// The default preset shrunk so a sample renders in about a second.
fn tiny_recipe(dir: &Path) -> PathBuf {
    write_tiny_recipe(dir, "crestereo")
}

const DEFAULT_RECIPE_TOML: &str = PRESETS[0].1;

fn generate_cmd(recipe: &Path, out: &Path, count: u64) -> Command {
    generate_with_seed(recipe, out, count, 5)
}

fn generate_with_seed(recipe: &Path, out: &Path, count: u64, seed: u64) -> Command {
    let mut c = test_support::generate_cmd(recipe, out, count);
    c.args(["--seed", &seed.to_string()]);
    c
}

fn run(mut c: Command) -> Output {
    c.stdin(Stdio::null()).output().expect("run stereogen")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Every index once, every file present with the checksum the manifest recorded, no leftovers.
fn assert_complete_dataset(out: &Path, count: u64) {
    let layout = DatasetLayout::new(out);
    let entries = Manifest::read(&layout.manifest()).expect("every manifest line parses");
    let mut indices: Vec<u64> = entries.iter().map(|e| e.index).collect();
    indices.sort();
    assert_eq!(
        indices,
        (0..count).collect::<Vec<_>>(),
        "each sample exactly once"
    );
    for e in &entries {
        for (key, rel) in e.files.all() {
            let path = layout.abs(rel);
            assert_listed_file_intact(&path, &e.sha256[key]);
        }
        stereo_io::read_disparity_exr(&layout.abs(&e.files.disp_left)).expect("readable disparity");
    }
    let mut files = Vec::new();
    for category in entries
        .iter()
        .map(|e| e.category.clone())
        .collect::<std::collections::BTreeSet<_>>()
    {
        files.extend(
            std::fs::read_dir(out.join(&category))
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned()),
        );
    }
    assert_eq!(files.len() as u64, 5 * count, "no stray files: {files:?}");
}

#[test]
fn killed_run_resumes_to_a_complete_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = tiny_recipe(dir.path());
    let out = dir.path().join("data");
    let count = 6;
    let mut child = generate_cmd(&recipe, &out, count)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let manifest = out.join("manifest.jsonl");
    let t0 = Instant::now();
    loop {
        let lines = std::fs::read_to_string(&manifest)
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if lines >= 2 {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(300), "no progress");
        assert!(
            child.try_wait().unwrap().is_none(),
            "generate ended before it could be killed"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL, in the middle of the next sample
    child.wait().unwrap();
    let done_before = Manifest::read(&manifest)
        .expect("manifest lines stay valid after SIGKILL")
        .len();
    assert!(done_before < count as usize);

    let o = run(generate_cmd(&recipe, &out, count));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(&format!("{done_before} already done")),
        "{}",
        stderr(&o)
    );
    assert_complete_dataset(&out, count);

    // A third run has nothing left to do.
    let o = run(generate_cmd(&recipe, &out, count));
    assert!(
        stderr(&o).contains(&format!("0 rendered, {count} already done")),
        "{}",
        stderr(&o)
    );
}

/// [`generate_cmd`] run with `extra` flags and the worker made to fail as
/// `STEREOGEN_FAULT=fault` says; returns the output and its stderr.
fn generate_with_fault(
    recipe: &Path,
    out: &Path,
    count: u64,
    fault: &str,
    extra: &[&str],
) -> (Output, String) {
    let mut c = generate_cmd(recipe, out, count);
    c.env("STEREOGEN_FAULT", fault).args(extra);
    let o = run(c);
    let err = stderr(&o);
    (o, err)
}

#[test]
fn crashed_and_hung_workers_are_restarted_and_the_run_completes() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = tiny_recipe(dir.path());
    let out = dir.path().join("data");
    let (o, err) = generate_with_fault(&recipe, &out, 4, "crash@1,hang@2", &["--timeout", "20"]);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("killed by signal 11"),
        "the crash is reported: {err}"
    );
    assert!(
        err.contains("gave no answer within 20s"),
        "the hang is reported: {err}"
    );
    assert!(err.contains("2 worker restart(s)"), "{err}");
    assert_complete_dataset(&out, 4);
}

#[test]
fn a_sample_that_always_crashes_is_recorded_and_the_rest_finish() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = tiny_recipe(dir.path());
    let out = dir.path().join("data");
    let (o, err) = generate_with_fault(&recipe, &out, 3, "crash-always@1", &["--retries", "1"]);
    assert!(!o.status.success());
    assert!(
        err.lines()
            .last()
            .unwrap()
            .starts_with("error: 1 sample(s) failed"),
        "{err}"
    );
    let failures = std::fs::read_to_string(out.join("failures.jsonl")).unwrap();
    assert!(failures.contains("\"index\":1"), "{failures}");
    let mut done: Vec<u64> = Manifest::read(&out.join("manifest.jsonl"))
        .unwrap()
        .iter()
        .map(|e| e.index)
        .collect();
    done.sort();
    assert_eq!(done, vec![0, 2]);
}

/// Runs a command that must fail fast and checks it printed exactly one line, the error.
fn assert_one_line_error(c: Command, expect: &str) {
    let o = run(c);
    assert!(!o.status.success());
    let err = stderr(&o);
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "one line expected, got: {err}");
    assert!(
        lines[0].starts_with("error: ") && lines[0].contains(expect),
        "expected {expect:?} in {err}"
    );
}

#[test]
fn bad_input_gives_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("data");
    // The default recipe with one edit, written as dir/NAME.
    let recipe_with = |name: &str, pattern: &str, with: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, DEFAULT_RECIPE_TOML.replace(pattern, with)).unwrap();
        path
    };

    let unknown = recipe_with("unknown.toml", "[render]", "[render]\nspp = 8");
    assert_one_line_error(generate_cmd(&unknown, &out, 1), "unknown field `spp`");

    let missing = recipe_with("missing.toml", "baseline_m = ", "# baseline_m = ");
    assert_one_line_error(
        generate_cmd(&missing, &out, 1),
        "missing field `baseline_m`",
    );

    let range = recipe_with("range.toml", "samples = 32", "samples = 0");
    assert_one_line_error(generate_cmd(&range, &out, 1), "`render.samples` is invalid");

    assert_one_line_error(
        generate_cmd(&dir.path().join("nope.toml"), &out, 1),
        "cannot read recipe",
    );

    let recipe = tiny_recipe(dir.path());
    let a_file = dir.path().join("a_file");
    std::fs::write(&a_file, b"x").unwrap();
    assert_one_line_error(
        generate_cmd(&recipe, &a_file.join("data"), 1),
        "cannot create output directory",
    );

    let mut c = generate_cmd(&recipe, &dir.path().join("d1"), 1);
    c.args(["--blender", "/no/such/blender"]);
    assert_one_line_error(c, "--blender /no/such/blender: no such file");

    let mut c = generate_cmd(&recipe, &dir.path().join("d2"), 1);
    c.args(["--blender", "/bin/false"]);
    assert_one_line_error(c, "cannot start Blender");

    let mut c = generate_cmd(&recipe, &dir.path().join("d3"), 1);
    c.env("STEREOGEN_PYTHON", "/no/such/python");
    assert_one_line_error(c, "STEREOGEN_PYTHON=/no/such/python");
}

#[test]
fn a_dataset_refuses_another_seed_or_recipe() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = tiny_recipe(dir.path());
    let out = dir.path().join("data");
    assert!(run(generate_cmd(&recipe, &out, 1)).status.success());
    assert_one_line_error(
        generate_with_seed(&recipe, &out, 1, 6),
        "was generated with --seed 5",
    );
    let other = dir.path().join("other.toml");
    write_replaced(&recipe, &other, "samples = 2\n", "samples = 3\n");
    assert_one_line_error(
        generate_cmd(&other, &out, 1),
        "was generated with another recipe",
    );
}

#[test]
fn plan_is_byte_identical_across_processes() {
    let plan = || run(stereogen_cmd(["plan", "--seed", "9", "--index", "41"]));
    let (a, b) = (plan(), plan());
    assert!(a.status.success());
    assert!(!a.stdout.is_empty());
    assert_eq!(a.stdout, b.stdout);
}
