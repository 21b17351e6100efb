//! Hostile input through the `stereogen` command, as a user meets it: each case ends in one
//! `error:` line and exit status 1 (never a signal, a panic or an allocation failure), before
//! Blender is started or anything is written outside the folders named.
//!
//! - a WebDataset export whose last tar header claims 4 TiB (GNU base-256), through `stats` and
//!   `export` (the report that opened the review: both died of SIGABRT allocating 4 TiB);
//! - scene specs for `render --spec`: an id that climbs out of `--out`, a gzip bomb, a sphere of
//!   four billion segments, a photo texture claiming 30000×30000 pixels, a pipe as a mesh file;
//! - `generate --count` beyond what one run can list; a farm folder claiming 10^11 shards.

use std::fs;
use std::path::Path;
use std::process::{Command, Output};

use stereo_io::{ReadOptions, WebDatasetOptions, export_webdataset};
use stereogen::plan::{AssetIndex, BaseColor, Recipe, SceneSpec, Shape, plan_scene};

use test_support::io_fixtures;

fn stereogen(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_stereogen"))
        .args(args.iter().map(|a| a.as_ref()))
        .env("NO_COLOR", "1")
        .output()
        .unwrap()
}

/// The command failed cleanly: status 1, and its last stderr line is one `error:` line holding
/// `want`.
fn refused(out: &Output, want: &str) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(1),
        "exit status (a signal has none): {stderr}"
    );
    let last = stderr.lines().last().unwrap_or_default().to_string();
    assert!(
        last.starts_with("error: ") && last.contains(want),
        "{stderr}"
    );
    assert!(
        !stderr.contains("panicked") && !stderr.contains("memory allocation"),
        "{stderr}"
    );
    last
}

#[test]
fn a_tar_header_claiming_4_tib_is_one_error_line_for_stats_and_export() {
    let dir = tempfile::tempdir().unwrap();
    let source = io_fixtures::mkdir(&dir.path().join("source"));
    io_fixtures::our_dataset(&source);
    let wds = dir.path().join("wds");
    let opts = WebDatasetOptions::default();
    export_webdataset(&source, &wds, None, &ReadOptions::default(), &opts).unwrap();
    let shard = wds.join("train-000000.tar");
    let members = stereo_io::datasets::webdataset::scan_shard(&shard).unwrap();
    let last = members.last().unwrap().offset as usize - 512;
    let mut bytes = fs::read(&shard).unwrap();
    io_fixtures::set_size_base256(&mut bytes, last, 4 << 40);
    fs::write(&shard, &bytes).unwrap();
    let want = "claims 4096 GiB of data";
    refused(&stereogen(&[&"stats", &wds]), want);
    let out = dir.path().join("x");
    refused(
        &stereogen(&[&"export", &wds, &"--format", &"crestereo", &"--out", &out]),
        want,
    );
    assert!(!out.join("train").exists());
}

/// Writes `spec` as a spec file and runs `render --spec` on it into `dir/out`.
fn render(dir: &Path, spec: &SceneSpec) -> Output {
    let file = dir.join("spec.json");
    fs::write(&file, spec.to_json()).unwrap();
    stereogen(&[&"render", &"--spec", &file, &"--out", &dir.join("out")])
}

fn spec() -> SceneSpec {
    plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 0)
}

#[test]
fn hostile_scene_specs_are_refused_before_blender_starts() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();

    let mut s = spec();
    s.id = "../../../escaped".into();
    refused(&render(d, &s), "key `id` is invalid");
    assert!(!d.join("escaped_left.png").exists());

    let mut s = spec();
    s.objects[0].shape = Shape::UvSphere {
        segments: u32::MAX,
        rings: u32::MAX,
    };
    refused(&render(d, &s), "need segments in 1..=1024");

    // A photo whose header claims 30000×30000 pixels: Blender would decode it whole.
    let photo = d.join("bomb.png");
    io_fixtures::write_png_claiming(&photo, 30000, 30000);
    let mut s = spec();
    s.objects[0].material.base = BaseColor::Image {
        path: photo,
        scale: 1.0,
        rotation: 0.0,
        fallback: [0.5; 3],
        texture_px: None,
        stretch: None,
    };
    refused(
        &render(d, &s),
        "30000x30000 pixels is over the readers' limits",
    );

    // A pipe named as a mesh file would hang the worker's importer.
    let fifo = d.join("mesh.obj");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let mut s = spec();
    s.objects[0].shape = Shape::MeshFile {
        candidates: vec![fifo],
        max_triangles: 1000,
    };
    refused(&render(d, &s), "not a regular file");

    // 80 MiB of JSON whitespace, gzip'd to 80 KB.
    let gz = d.join("bomb.scene.json.gz");
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    std::io::Write::write_all(&mut enc, &vec![b' '; 80 << 20]).unwrap();
    fs::write(&gz, enc.finish().unwrap()).unwrap();
    let out = stereogen(&[&"render", &"--spec", &gz, &"--out", &d.join("out")]);
    refused(&out, "longer than the limit of 64 MiB");
}

#[test]
fn counts_no_run_can_hold_are_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("data");
    let o = stereogen(&[&"generate", &"--out", &out, &"--count", &"1000000000000"]);
    refused(&o, "more than 100000000 samples for one run");

    // A farm folder whose one shard directory claims a farm of 10^11 shards: the merge report
    // lists a few missing shards and counts the rest, at once.
    let farm = dir.path().join("farm");
    fs::create_dir_all(farm.join("shards/00000000000-of-99999999999")).unwrap();
    let t0 = std::time::Instant::now();
    let o = stereogen(&[&"merge", &farm]);
    assert!(t0.elapsed().as_secs() < 30);
    refused(&o, "problem(s)");
    let report = String::from_utf8_lossy(&o.stdout);
    assert!(
        report.contains("problem: 99999999978 more of the 99999999999 shards are missing"),
        "{report}"
    );
    assert!(report.lines().count() < 100, "{report}");
}

#[test]
fn the_recipe_limit_is_the_limits_policy() {
    assert_eq!(
        stereogen::plan::recipe::MAX_RECIPE_BYTES,
        stereo_io::limits::MAX_DOCUMENT_BYTES
    );
    let dir = tempfile::tempdir().unwrap();
    let recipe = dir.path().join("huge.toml");
    let f = fs::File::create(&recipe).unwrap();
    f.set_len(stereo_io::limits::MAX_DOCUMENT_BYTES + 1)
        .unwrap();
    let out = dir.path().join("data");
    let o = stereogen(&[
        &"generate",
        &"--recipe",
        &recipe,
        &"--out",
        &out,
        &"--count",
        &"1",
    ]);
    refused(&o, "not a regular file of at most 64 MiB");
}
