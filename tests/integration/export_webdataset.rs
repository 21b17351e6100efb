//! `stereogen export --format webdataset` with the real CLI: a rendered dataset of ours as tar
//! shards read back equal to the source (its EXRs byte for byte) by `open_dataset`, by `stats`
//! and `report` and by the Python module; and an export killed with SIGKILL mid-way that a
//! re-run of the same command finishes to the bytes of a clean export.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use test_support::files::files_with_bytes as files;
use test_support::{
    export_cmd, output_text, pinned_venv,
    python_envs::{MATURIN_PINS, install_stereogen_module, repo_root},
    stats_cmd, stereogen_cmd,
};

use serde_json::Value;
use stereo_io::{DatasetFormat, ImageEncoding, WritableFormat, create_writer, open_dataset};

fn export(data: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut c = export_cmd(data, "webdataset", out);
    c.args(extra);
    c
}

fn run(c: &mut Command) -> String {
    let out = c.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    stderr
}

#[test]
fn a_rendered_dataset_as_shards_reads_back_as_it_was() {
    let t = tempfile::tempdir().unwrap();
    let ours = test_support::generate_tiny_dataset(t.path(), "ours", 3, 7);
    let shards = t.path().join("shards");
    let said = run(&mut export(
        &ours,
        &shards,
        &["--shard-size", "1B", "--splits", "train=0.67,val=0.33"],
    ));
    assert!(
        said.contains("exported 3 sample(s) as 3 WebDataset shard(s)"),
        "{said}"
    );
    for name in [
        "train.index.json",
        "val.index.json",
        "dataset.json",
        "train-000000.tar",
    ] {
        assert!(shards.join(name).is_file(), "{name}");
    }
    let source = open_dataset(&ours, None).unwrap();
    let read = open_dataset(&shards, None).unwrap();
    assert_eq!((read.format(), read.len()), (DatasetFormat::WebDataset, 3));
    for i in 0..3 {
        let got = read.sample(i).unwrap();
        let k = (0..3)
            .find(|&k| source.sample(k).unwrap().meta.id == got.meta.id)
            .expect("a sample of the source");
        let want = source.sample(k).unwrap();
        assert_eq!((got.left, got.right), (want.left, want.right));
        assert_eq!(got.disp_left, want.disp_left);
        assert_eq!(got.disp_right, want.disp_right);
        assert_eq!(
            got.meta.extra.get("category"),
            want.meta.extra.get("category")
        );
    }
    // An existing export is kept unless --force.
    let refused = export(&ours, &shards, &[]).output().unwrap();
    let e = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && e.contains("--force"), "{e}");
    run(&mut export(&ours, &shards, &["--force"]));

    // The readers of our folders read the export, from the shards as they are.
    stats_equal_the_source(&ours, &shards, t.path());
    report_from_shards(&ours, &shards);
    let card = std::fs::read_to_string(shards.join("README.md")).unwrap();
    assert!(
        !card.contains("depth_left") && !card.contains("Maps beside"),
        "no map in the card of an export without maps"
    );
    python_reads_the_export(&ours, &shards, t.path(), false);
}

/// A rendered dataset with every map (`[render] outputs`) exported: the maps travel as members
/// (`<key>.depth_left.exr`, ...) and read back unchanged through `open_dataset` and the Python
/// module (which also checks them against the disparity and the instance table), and the
/// dataset card describes them with the semantic classes.
#[test]
fn maps_travel_in_the_shards_and_read_back_unchanged() {
    use stereogen::plan::OutputMap;
    let t = tempfile::tempdir().unwrap();
    let mut recipe = test_support::tiny_recipe("crestereo");
    recipe.render.outputs = OutputMap::ALL.to_vec();
    let recipe_path = t.path().join("tiny-maps.toml");
    std::fs::write(&recipe_path, toml::to_string(&recipe).unwrap()).unwrap();
    let ours = t.path().join("ours");
    test_support::run_ok(test_support::generate_cmd(&recipe_path, &ours, 3).args(["--seed", "7"]));
    let shards = t.path().join("shards");
    run(&mut export(&ours, &shards, &["--shard-size", "1B"]));
    let source = open_dataset(&ours, None).unwrap();
    let read = open_dataset(&shards, None).unwrap();
    for i in 0..3 {
        let got = read.sample(i).unwrap();
        let k = (0..3)
            .find(|&k| source.id(k) == Some(got.meta.id.as_str()))
            .expect("a sample of the source");
        let want = source.sample(k).unwrap();
        let maps = source.maps(k).unwrap();
        assert_eq!(maps.kinds(), stereo_io::MapKind::ALL, "{}", want.meta.id);
        assert_eq!(read.maps(i).unwrap(), maps, "{}", want.meta.id);
        assert!(!want.meta.instances.is_empty());
        assert_eq!(got.meta.instances, want.meta.instances);
        assert_eq!(got.disp_left, want.disp_left);
    }
    let card = std::fs::read_to_string(shards.join("README.md")).unwrap();
    for want in [
        "| `depth_left.exr` |",
        "| `normals_right.exr` |",
        "| `semantic_left.png` |",
        "## Maps beside the disparity",
        "| class id | class |",
    ] {
        assert!(card.contains(want), "the card lacks {want}:\n{card}");
    }
    python_reads_the_export(&ours, &shards, t.path(), true);
}

/// `stats.json` without what says differently by design (where the dataset is).
fn comparable(mut v: Value) -> Value {
    let o = v.as_object_mut().unwrap();
    for k in ["dataset", "notes"] {
        o.remove(k);
    }
    v
}

/// `a` and `b` equal, numbers to a relative 1e-9 (the parallel sums add in another order).
fn assert_close(a: &Value, b: &Value, at: &str) {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!(
                (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1.0),
                "{at}: {x} != {y}"
            );
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{at}: lengths");
            for (i, (x, y)) in x.iter().zip(y).enumerate() {
                assert_close(x, y, &format!("{at}[{i}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            let keys = |m: &serde_json::Map<String, Value>| m.keys().cloned().collect::<Vec<_>>();
            assert_eq!(keys(x), keys(y), "{at}: keys");
            for (k, x) in x {
                assert_close(x, &y[k], &format!("{at}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "{at}"),
    }
}

/// `stats --verify` of the export (written into it, as by default) gives the source's figures,
/// every member matching the manifest's checksum — the object-level figures too, since the
/// SceneSpecs travel in the shards; `--check` decides alike.
fn stats_equal_the_source(ours: &Path, shards: &Path, tmp: &Path) {
    let source_dir = tmp.join("source-stats");
    let said = run_out(stats_cmd(ours).arg("--out").arg(&source_dir));
    assert!(said.contains("verdict:"), "{said}");
    let said = run_out(stats_cmd(shards).arg("--verify"));
    assert!(
        said.contains("verified: every file of the 3 samples"),
        "{said}"
    );
    assert!(
        !said.lines().any(|l| l.starts_with("NOTE ")),
        "nothing is left out of an export of ours: {said}"
    );
    let read =
        |p: PathBuf| -> Value { serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap() };
    let (want, got) = (
        read(source_dir.join("stats.json")),
        read(shards.join("stats.json")),
    );
    assert_eq!(got["samples"], 3);
    assert!(
        want["overall"]["objects"]["count"].as_u64().unwrap() > 0,
        "the source has an object-level sample"
    );
    assert_eq!(
        got["overall"]["objects"]["count"], want["overall"]["objects"]["count"],
        "the export's SceneSpecs give the same objects"
    );
    assert!(got["overall"]["pixels"]["valid"].as_u64().unwrap() > 0);
    assert_close(&comparable(got), &comparable(want), "stats.json");
    let check = |d: &Path| {
        let out = stats_cmd(d)
            .arg("--check")
            .arg("--out")
            .arg(tmp.join("check"))
            .output()
            .unwrap();
        out.status.success()
    };
    assert_eq!(check(shards), check(ours), "stats --check decides alike");
}

/// `report` of the export writes its page (statistics, gallery pictures from the shards) and
/// says that it carries no failure logs.
fn report_from_shards(ours: &Path, shards: &Path) {
    let said = run_out(stereogen_cmd(["report"]).arg(shards));
    assert!(said.contains("3 samples, 3 in the gallery"), "{said}");
    let html = std::fs::read_to_string(shards.join("report.html")).unwrap();
    for want in [
        "data:image/jpeg;base64,",
        "data:image/png;base64,",
        "carries no failures.jsonl",
        "<svg",
    ] {
        assert!(html.contains(want), "report.html lacks {want}");
    }
    assert!(
        !html.contains("carry no SceneSpecs"),
        "the SceneSpecs travel"
    );
    assert!(!html.contains("cannot decode") && !html.contains("missing from its sample"));
    let source = tempfile::tempdir().unwrap();
    let said_source = run_out(
        stereogen_cmd(["report"])
            .arg(ours)
            .arg("--out")
            .arg(source.path().join("r.html")),
    );
    let gallery = |s: &str| {
        s.split_once(" samples, ")
            .map(|(_, r)| r.split(',').next().unwrap().to_string())
    };
    assert_eq!(
        gallery(&said),
        gallery(&said_source),
        "{said}\n{said_source}"
    );
}

/// The Python module opens the export as it opens the source (pytest
/// crates/stereogen-py/pytests/test_webdataset.py, in the venv of tests/integration/io_python.rs).
fn python_reads_the_export(ours: &Path, shards: &Path, tmp: &Path, maps: bool) {
    use pinned_venv::{ensure_venv, run as run_checked};
    let venv = ensure_venv("venv-test", MATURIN_PINS);
    install_stereogen_module(&venv);
    let fixture = tmp.join("webdataset-fixture.json");
    let facts = serde_json::json!({"source": ours, "export": shards, "len": 3, "maps": maps});
    std::fs::write(&fixture, facts.to_string()).unwrap();
    let said = run_checked(
        Command::new(venv.join("bin/python"))
            .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
            .arg(repo_root().join("crates/stereogen-py/pytests/test_webdataset.py"))
            .env("STEREOGEN_PY_WEBDATASET", &fixture),
        "pytest",
    );
    assert!(
        said.contains("passed") && !said.contains("skipped"),
        "{said}"
    );
}

/// Runs `c`, asserting success; its stdout and stderr.
fn run_out(c: &mut Command) -> String {
    let out = c.output().unwrap();
    let all = output_text(&out);
    assert!(out.status.success(), "{all}");
    all
}

/// A dataset that takes the export a few seconds: CREStereo's layout, written directly.
fn many_samples(root: &Path, n: usize) -> PathBuf {
    let mut w = create_writer(WritableFormat::Crestereo, root, ImageEncoding::Lossless).unwrap();
    let (width, height) = (320, 240);
    for k in 0..n {
        let noise = |salt: usize| -> Vec<u8> {
            (0..width * height * 3)
                .map(|i| ((i * 2_654_435_761 + k * 97 + salt) >> 7) as u8)
                .collect()
        };
        let image = |salt| stereo_io::RgbImage {
            width,
            height,
            data: noise(salt),
        };
        let mut disp = stereo_io::DisparityMap::new(width, height);
        disp.data
            .iter_mut()
            .enumerate()
            .for_each(|(i, d)| *d = (i % 97) as f32 * 0.5);
        disp.valid.fill(true);
        let sample = stereo_io::StereoSample {
            left: image(1),
            right: image(2),
            disp_left: disp.clone(),
            disp_right: Some(disp),
            valid_left: None,
            meta: Default::default(),
        };
        w.write(k, &format!("{}/{k:07}", ["tree", "hole"][k % 2]), &sample)
            .unwrap();
    }
    root.to_path_buf()
}

#[test]
fn an_export_killed_mid_way_is_finished_by_the_same_command() {
    let t = tempfile::tempdir().unwrap();
    let source = many_samples(&t.path().join("source"), 120);
    let args = ["--shard-size", "2MiB", "--shuffle-seed", "5"];
    let clean = t.path().join("clean");
    run(&mut export(&source, &clean, &args));

    let out = t.path().join("killed");
    let mut child = export(&source, &out, &args)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let shard = |n: usize| out.join(format!("train-{n:06}.tar"));
    while !shard(1).exists() && start.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL: no chance to clean up
    child.wait().unwrap();
    assert!(shard(1).exists(), "two shards written before the kill");
    assert!(
        !out.join("train.index.json").exists(),
        "killed before the end"
    );
    let e = open_dataset(&out, None)
        .err()
        .expect("an unfinished export is no dataset")
        .to_string();
    assert!(e.contains("unfinished WebDataset export"), "{e}");

    let said = run(&mut export(&source, &out, &args));
    assert!(!said.contains("(0 kept from an interrupted run)"), "{said}");
    assert!(
        files(&out) == files(&clean),
        "the resumed export differs from a clean one"
    );
}
