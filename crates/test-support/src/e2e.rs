//! Helpers of the end-to-end tests that run the real renderer and the real CLIs (`stereogen`,
//! `crestereo`).

use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

use stereo_io::DisparityMap;
use stereogen::dataset::DatasetLayout;
use stereogen::plan::recipe::CountRange;
use stereogen::plan::{Dist, Recipe, SceneSpec};
use stereogen::render::{RenderService, WorkerConfig, WorkerOptions};

use crate::run::run_ok;

/// The worker configuration every test uses: the real Blender runtime, installed on first use.
pub fn worker_config() -> WorkerConfig {
    static CFG: OnceLock<WorkerConfig> = OnceLock::new();
    CFG.get_or_init(|| {
        let options = WorkerOptions {
            threads: Some(1),
            startup_timeout: Duration::from_secs(300),
            render_timeout: Duration::from_secs(300),
            retries: 1,
            ..WorkerOptions::default()
        };
        options
            .resolve(1)
            .expect("a Blender runtime (installed by `stereogen setup`)")
    })
    .clone()
}

/// A rendered sample read back from the files the generator wrote.
pub struct RenderedPair {
    pub left: DisparityMap,
    pub right: DisparityMap,
    pub dir: tempfile::TempDir,
    pub layout: DatasetLayout,
    pub entry: stereogen::dataset::ManifestEntry,
    /// The assets the worker could not load and left out of the scene.
    pub skipped_assets: Vec<stereogen::assets::SkippedAsset>,
}

/// Renders `spec` with a real worker, finishes it into a fresh dataset dir and reads both maps.
pub fn render(service: &mut RenderService, spec: &SceneSpec) -> RenderedPair {
    let rendered = service.render(spec, |_| None).expect("render");
    let dir = tempfile::tempdir().expect("tempdir");
    let layout = DatasetLayout::new(dir.path());
    let reply = &rendered.reply;
    let entry = stereogen::dataset::finalize_sample(
        &layout,
        spec,
        &reply.files,
        &reply.report.notes,
        0.0,
        &reply.report.timings,
    )
    .expect("finalize");
    let (left, _) =
        stereo_io::read_disparity_exr(&layout.abs(&entry.files.disp_left)).expect("left exr");
    let (right, _) =
        stereo_io::read_disparity_exr(&layout.abs(&entry.files.disp_right)).expect("right exr");
    RenderedPair {
        left,
        right,
        dir,
        layout,
        entry,
        skipped_assets: reply.report.skipped_assets.clone(),
    }
}

/// The `stereogen` binary that `cargo test --workspace` built next to this test executable.
///
/// Run these tests through `cargo test --workspace` (as `.ci/run` does): `cargo test -p
/// stereogen-e2e` alone rebuilds the library but not this binary, and would test an old one.
pub fn stereogen_bin() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let profile_dir = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("target/<profile>/deps");
    let bin = profile_dir.join("stereogen");
    assert!(
        bin.is_file(),
        "{} is missing: run the tests with `cargo test --workspace` so the CLI is built",
        bin.display()
    );
    bin
}

/// The `crestereo` binary (the trainer's CLI) that `cargo test --workspace` built next to this
/// test executable (same caveat as [`stereogen_bin`]).
pub fn crestereo_bin() -> PathBuf {
    let bin = stereogen_bin().with_file_name("crestereo");
    assert!(
        bin.is_file(),
        "{} is missing: run the tests with `cargo test --workspace` so the CLI is built",
        bin.display()
    );
    bin
}

/// `crestereo train --no-progress --config CONFIG --out RUN`, with the trainer's log at `warn`.
pub fn crestereo_train_cmd(
    config: &std::path::Path,
    run: &std::path::Path,
) -> std::process::Command {
    let mut c = std::process::Command::new(crestereo_bin());
    c.args(["train", "--no-progress", "--config"])
        .arg(config)
        .arg("--out")
        .arg(run)
        .env("CRESTEREO_LOG", "warn");
    c
}

/// `stereogen ARGS` as every test runs it: the binary built next to the test, no stdin, and none
/// of the environment that steers a run from outside (`STEREOGEN_FAULT`, `STEREOGEN_SHARD`); a
/// test that wants them sets them on the command.
pub fn stereogen_cmd<I, S>(args: I) -> std::process::Command
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let mut c = std::process::Command::new(stereogen_bin());
    c.args(args)
        .stdin(std::process::Stdio::null())
        .env_remove("STEREOGEN_FAULT")
        .env_remove("STEREOGEN_SHARD");
    c
}

/// `stereogen generate` of `count` samples of `recipe` (a preset name or a recipe file) into
/// `out`, with one Cycles thread and no progress bar; add `--seed`, `--shard`, ... to it.
pub fn generate_cmd(
    recipe: impl AsRef<std::ffi::OsStr>,
    out: &std::path::Path,
    count: u64,
) -> std::process::Command {
    let mut c = stereogen_cmd(["generate", "--no-progress", "--threads", "1"]);
    c.arg("--count")
        .arg(count.to_string())
        .arg("--recipe")
        .arg(recipe)
        .arg("--out")
        .arg(out);
    c
}

/// `stereogen audit DATASET` with one thread; add `--check`, `--all`, ... to it.
pub fn audit_cmd(dataset: &std::path::Path) -> std::process::Command {
    let mut c = stereogen_cmd(["audit"]);
    c.arg(dataset).args(["--threads", "1"]);
    c
}

/// `stereogen export DATASET --format FORMAT --out OUT`; add `--force`, `--jpeg`, ... to it.
pub fn export_cmd(
    dataset: &std::path::Path,
    format: &str,
    out: &std::path::Path,
) -> std::process::Command {
    let mut c = stereogen_cmd(["export"]);
    c.arg(dataset).args(["--format", format, "--out"]).arg(out);
    c
}

/// `stereogen stats DATASET`; add `--check`, `--verify`, `--out`, ... to it.
pub fn stats_cmd(dataset: &std::path::Path) -> std::process::Command {
    let mut c = stereogen_cmd(["stats"]);
    c.arg(dataset);
    c
}

/// `stereogen merge OUT`; add `--verify`, `--webdataset DIR`, ... to it.
pub fn merge_cmd(out: &std::path::Path) -> std::process::Command {
    let mut c = stereogen_cmd(["merge"]);
    c.arg(out);
    c
}

/// `stereogen farm SCHEDULER` of `count` samples in `tasks` tasks of `recipe` into `out`, with
/// one Cycles thread and the `stereogen` binary under test; add `--seed`, ... to it.
pub fn farm_cmd(
    scheduler: &str,
    recipe: &std::path::Path,
    out: &std::path::Path,
    count: u64,
    tasks: u64,
) -> std::process::Command {
    let mut c = stereogen_cmd(["farm", scheduler, "--threads", "1"]);
    c.arg("--count")
        .arg(count.to_string())
        .arg("--tasks")
        .arg(tasks.to_string())
        .arg("--recipe")
        .arg(recipe)
        .arg("--out")
        .arg(out)
        .arg("--stereogen")
        .arg(stereogen_bin());
    c
}

/// A preset shrunk so a sample renders in about a second: 64×48, 2 samples, few objects.
pub fn tiny_recipe(preset: &str) -> Recipe {
    let mut r = Recipe::preset(preset).expect("preset");
    r.camera.width = 64;
    r.camera.height = 48;
    r.render.samples = 2;
    r.render.denoise = false;
    // Procedural content only: fast, and independent of the content pack.
    r.sources.builtin_pack = false;
    r.placement.disparity_px = Dist::uniform(3.0, 20.0);
    r.placement.background_disparity_px = Dist::uniform(0.5, 1.5);
    r.trees.branches = CountRange { min: 3, max: 4 };
    for c in &mut r.categories {
        // The categories' own render keys (the presets' per-category picks) would undo the
        // 2 samples above.
        c.render = None;
        c.objects = CountRange { min: 2, max: 3 };
    }
    r
}

/// Writes [`tiny_recipe`] as TOML into `dir` and returns its path.
pub fn write_tiny_recipe(dir: &std::path::Path, preset: &str) -> PathBuf {
    let path = dir.join(format!("tiny-{preset}.toml"));
    std::fs::write(
        &path,
        toml::to_string(&tiny_recipe(preset)).expect("recipes serialise"),
    )
    .expect("write recipe");
    path
}

/// Renders `count` scenes of the tiny `crestereo` recipe with the real CLI into `dir/<name>`.
pub fn generate_tiny_dataset(dir: &std::path::Path, name: &str, count: u64, seed: u64) -> PathBuf {
    generate_tiny_preset(dir, "crestereo", name, count, seed)
}

/// `stereogen generate` of `count` scenes of the tiny version of `preset` into `dir/<name>`
/// (one Cycles thread, no progress bar, no stdin), and that output folder.
fn tiny_generate(
    dir: &std::path::Path,
    preset: &str,
    name: &str,
    count: u64,
) -> (std::process::Command, PathBuf) {
    let recipe = write_tiny_recipe(dir, preset);
    let out = dir.join(name);
    (generate_cmd(&recipe, &out, count), out)
}

/// Renders `count` scenes of the tiny version of `preset` with the real CLI into `dir/<name>`.
pub fn generate_tiny_preset(
    dir: &std::path::Path,
    preset: &str,
    name: &str,
    count: u64,
    seed: u64,
) -> PathBuf {
    let (mut c, out) = tiny_generate(dir, preset, name, count);
    run_ok(c.args(["--seed", &seed.to_string()]));
    out
}

/// A dataset whose only sample failed: `generate` of one tiny scene into `dir/<name>` with the
/// worker made to raise on it (`STEREOGEN_FAULT=raise@0`); the run must fail.
pub fn generate_failed_dataset(dir: &std::path::Path, name: &str) -> PathBuf {
    let (mut c, out) = tiny_generate(dir, "crestereo", name, 1);
    let o = c
        .env("STEREOGEN_FAULT", "raise@0")
        .output()
        .expect("run stereogen");
    assert!(
        !o.status.success(),
        "a run whose only sample raised succeeded"
    );
    out
}

/// SHA-256 of a file as lowercase hex, recomputed with coreutils' `sha256sum`: independent of the
/// generator's own hashing, so the manifest's checksums are checked by code nobody here wrote.
pub fn sha256_hex(path: &std::path::Path) -> String {
    let out = run_ok(std::process::Command::new("sha256sum").arg(path));
    String::from_utf8(out.stdout)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .to_string()
}

/// The `audit.json` an audit wrote into dataset `data`.
pub fn audit_report(data: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(data.join("audit.json")).unwrap()).unwrap()
}

/// The audited samples of an `audit.json`, by sample id.
pub fn audit_samples_by_id(
    report: &serde_json::Value,
) -> std::collections::BTreeMap<String, serde_json::Value> {
    report["samples"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["id"].as_str().unwrap().to_string(), s.clone()))
        .collect()
}

/// Records the current checksum (by [`sha256_hex`]) of file `key` of sample `id` in the manifest
/// of dataset `data`, as if the generator had written that file itself: a test that corrupts a
/// file and re-signs it leaves only the geometry to catch it.
pub fn resign(data: &std::path::Path, id: &str, key: &str) {
    let path = data.join("manifest.jsonl");
    let mut out = String::new();
    for line in std::fs::read_to_string(&path).unwrap().lines() {
        let mut v: serde_json::Value = serde_json::from_str(line).unwrap();
        if v["id"] == id {
            let rel = v["files"][key].as_str().unwrap().to_string();
            v["sha256"][key] = serde_json::Value::String(sha256_hex(&data.join(rel)));
        }
        out += &serde_json::to_string(&v).unwrap();
        out.push('\n');
    }
    std::fs::write(path, out).unwrap();
}

/// The first scene of each category of the default preset with `seed`, at `width`×`height`
/// with `samples` per pixel and the maps `outputs`.
pub fn one_spec_per_category(
    seed: u64,
    size: (u32, u32),
    samples: u32,
    outputs: &[stereogen::plan::OutputMap],
) -> Vec<SceneSpec> {
    let recipe = Recipe::preset(stereogen::plan::recipe::DEFAULT_PRESET).unwrap();
    let wanted = recipe.categories.iter().map(|c| c.name.clone()).collect();
    first_spec_of_each(&recipe, seed, (size, samples, outputs), wanted, |s| {
        s.category.clone()
    })
}

/// The first scene of each background kind (wall, room, environment) of the `wmgstereo`
/// preset with `seed`, made small like [`one_spec_per_category`]'s.
pub fn one_spec_per_background(
    seed: u64,
    size: (u32, u32),
    samples: u32,
    outputs: &[stereogen::plan::OutputMap],
) -> Vec<SceneSpec> {
    use stereogen::plan::BackgroundKind;
    let recipe = Recipe::preset("wmgstereo").unwrap();
    let kinds = [
        BackgroundKind::Wall,
        BackgroundKind::Room,
        BackgroundKind::Environment,
    ];
    let wanted = kinds.iter().map(|k| format!("{k:?}")).collect();
    first_spec_of_each(&recipe, seed, (size, samples, outputs), wanted, |s| {
        format!("{:?}", s.background_kind())
    })
}

/// The first of the recipe's first 64 scenes for each value of `key`, shrunk to (size, samples
/// per pixel, maps); panics unless exactly the values `wanted` come up.
fn first_spec_of_each(
    recipe: &Recipe,
    seed: u64,
    ((width, height), samples, outputs): ((u32, u32), u32, &[stereogen::plan::OutputMap]),
    mut wanted: Vec<String>,
    key: impl Fn(&SceneSpec) -> String,
) -> Vec<SceneSpec> {
    let mut specs: Vec<SceneSpec> = Vec::new();
    for index in 0..64 {
        let mut spec = stereogen::plan::plan_scene(
            recipe,
            &stereogen::assets::AssetIndex::default(),
            seed,
            index,
        );
        if specs.iter().any(|s| key(s) == key(&spec)) {
            continue;
        }
        spec.rig.width = width;
        spec.rig.height = height;
        spec.render.recipe.samples = samples;
        spec.render.recipe.outputs = outputs.to_vec();
        specs.push(spec);
    }
    let mut found: Vec<String> = specs.iter().map(&key).collect();
    found.sort_unstable();
    wanted.sort_unstable();
    assert_eq!(found, wanted, "missing from the first 64 samples");
    specs
}

/// Asserts that `path`, a file a manifest lists, is there and that its SHA-256 (by
/// [`sha256_hex`]) is `want`, the checksum the manifest recorded.
pub fn assert_listed_file_intact(path: &std::path::Path, want: &str) {
    assert!(path.is_file(), "{} is listed but missing", path.display());
    assert_eq!(
        sha256_hex(path),
        want,
        "{} does not match its manifest checksum",
        path.display()
    );
}

/// A farm output of `count` samples of the tiny `crestereo` recipe (seed 9) in two shards, each
/// rendered by its own `stereogen generate --shard` process.
pub fn two_shard_farm(dir: &std::path::Path, count: u64) -> PathBuf {
    let recipe = write_tiny_recipe(dir, "crestereo");
    let out = dir.join("farm");
    for shard in ["0/2", "1/2"] {
        run_ok(generate_cmd(&recipe, &out, count).args(["--seed", "9", "--shard", shard]));
    }
    out
}
