//! `crestereo synth | train | eval | plot` end to end through the binary, and their errors.

use std::path::Path;
use std::process::{Command, Output};
use test_support::output_text;

use crate::{loss_columns, short_run};
fn crestereo(args: &[&str]) -> Output {
    crestereo_logging(args, "warn")
}

fn crestereo_logging(args: &[&str], level: &str) -> Output {
    Command::new(env!("CARGO_BIN_EXE_crestereo"))
        .args(args)
        .env("CRESTEREO_LOG", level)
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> String {
    ok_at(args, "warn")
}

/// `ok` with the info log shown (where the data and its splits are announced).
fn ok_logged(args: &[&str]) -> String {
    ok_at(args, "info")
}

fn ok_at(args: &[&str], level: &str) -> String {
    let out = crestereo_logging(args, level);
    let text = output_text(&out);
    assert!(out.status.success(), "crestereo {args:?} failed:\n{text}");
    text
}

fn fails(args: &[&str]) -> String {
    let out = crestereo(args);
    assert!(!out.status.success(), "crestereo {args:?} should fail");
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(err.lines().count() <= 3, "error is not short:\n{err}");
    err
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `eval` of the run's weights on `data` with a short inference (2 iterations, 1 stage), its
/// report written to `json`.
fn short_eval<'a>(data: &'a str, run: &'a Path, json: &'a Path) -> Vec<&'a str> {
    let args = ["eval", "--data", data, "--weights", s(run), "--iters", "2"];
    let mut v = args.to_vec();
    v.extend(["--stages", "1", "--json", s(json)]);
    v
}

#[test]
fn train_then_eval_then_plot() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let run = dir.path().join("run");
    ok(&[
        "synth",
        "--out",
        s(&data),
        "--count",
        "3",
        "--size",
        "64x128",
        "--seed",
        "4",
    ]);
    let mut args = vec![
        "train",
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--steps",
        "3",
        "--val",
        s(&data),
        "--val-every",
        "3",
        "--val-limit",
        "2",
    ];
    args.extend(short_run::TINY_TRAINING);
    let text = ok(&args);
    assert!(text.contains("step 3 of 3"), "{text}");
    for f in [
        "config.toml",
        "train_log.csv",
        "val_log.csv",
        "checkpoints/step-00000003/model.mpk",
        "checkpoints/step-00000003/optimizer.mpk",
        "checkpoints/step-00000003/state.json",
    ] {
        assert!(run.join(f).is_file(), "{f} missing");
    }
    let val = std::fs::read_to_string(run.join("val_log.csv")).unwrap();
    assert_eq!(val.lines().count(), 2, "{val}");

    // Resuming a finished run does nothing; a different seed is refused.
    let mut resume = vec!["train", "--out", s(&run), "--resume", "--no-progress"];
    ok(&resume);
    resume.extend(["--seed", "9"]);
    let e = fails(&resume);
    assert!(
        e.contains("differs from the one this run started with"),
        "{e}"
    );

    let json = dir.path().join("eval.json");
    let fg = data.join("foreground");
    let mut args = short_eval(s(&data), &run, &json);
    args.extend(["--fg-masks", s(&fg)]);
    let table = ok(&args);
    for label in [
        "EPE (AvgErr)",
        "Bad-2 %",
        "D1 %",
        "A95",
        "non-occ",
        "mxIoU",
        "mxIoUbd (p=4)",
    ] {
        assert!(table.contains(label), "{label} missing from:\n{table}");
    }
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(report["images"], 3);
    assert!(report["mean_all"]["epe"].as_f64().unwrap().is_finite());
    assert!(
        report["mean_nonocc"]["count"].as_u64().unwrap()
            < report["mean_all"]["count"].as_u64().unwrap()
    );
    assert_eq!(report["per_image"][0]["nonocc_source"], "left-right-check");
    assert!((0.0..=1.0).contains(&report["mean_mxiou"].as_f64().unwrap()));
    let csv = std::fs::read_to_string(dir.path().join("eval.per_image.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4);
    // The untrained baseline evaluates too.
    ok(&[
        "eval",
        "--data",
        s(&data),
        "--untrained-seed",
        "1",
        "--iters",
        "2",
        "--stages",
        "1",
        "--limit",
        "1",
        "--json",
        s(&dir.path().join("u.json")),
    ]);

    let png = dir.path().join("loss.png");
    ok(&["plot", s(&run), "--out", s(&png)]);
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
}

#[test]
fn bad_input_gets_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, "batch_sise = 4\n[[datasets]]\npath = \"x\"\n").unwrap();
    let (run, data) = (dir.path().join("r"), dir.path().join("d"));
    let (cfg, run, data, here) = (s(&cfg), s(&run), s(&data), s(dir.path()));
    // Each command fails with a short message that says this.
    let refused = |args: &[&str], says: &str| {
        let e = fails(args);
        assert!(e.contains(says), "crestereo {args:?}: {e}");
    };
    refused(&["train", "--config", cfg, "--out", run], "batch_sise");
    let no_dir = [
        "train",
        "--data",
        "/no/such/dir",
        "--out",
        run,
        "--steps",
        "2",
    ];
    refused(&no_dir, "/no/such/dir");
    refused(&["train", "--out", run], "no training data");
    let e = fails(&["eval", "--data", here, "--weights", "/no/such.mpk"]);
    assert!(
        e.contains("holds no samples") || e.contains("cannot open"),
        "{e}"
    );
    ok(&["synth", "--out", data, "--count", "1"]);
    refused(
        &["eval", "--data", data, "--weights", "/no/such.mpk"],
        "/no/such.mpk",
    );
    refused(&["eval", "--data", data], "no weights");
    refused(
        &["eval", "--data", data, "--weights", here],
        "holds no checkpoint",
    );
}

/// Five synthetic 64x128 pairs (seed 6) in DIR/synth, the source of the WebDataset tests.
fn synth_five(dir: &Path) -> std::path::PathBuf {
    let synth = dir.join("synth");
    ok(&[
        "synth",
        "--out",
        s(&synth),
        "--count",
        "5",
        "--size",
        "64x128",
        "--seed",
        "6",
    ]);
    synth
}

/// `--data DIR:webdataset` streams the shards (2 streams, a buffer of 2 samples each): a run
/// stopped with `--stop-at` and resumed logs the same losses as one run straight through, and a
/// resume with other streaming settings is refused (they decide the data order).
#[test]
fn a_streamed_webdataset_run_resumes_bit_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (synth, shards) = (synth_five(dir.path()), dir.path().join("shards"));
    let summary = stereo_io::export_webdataset(
        &synth,
        &shards,
        None,
        &stereo_io::ReadOptions::default(),
        &stereo_io::WebDatasetOptions {
            shard_bytes: 1,
            shuffle_seed: 4,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((summary.samples, summary.shards), (5, 5));
    let data = format!("{}:webdataset", s(&shards));
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec!["train", "--data", &data, "--out", s(out), "--steps", "6"];
        args.extend(["--streams", "2", "--shuffle-buffer", "2"]);
        args.extend(short_run::TINY_TRAINING);
        args.extend(extra);
        ok(&args)
    };
    let (straight, split) = (dir.path().join("straight"), dir.path().join("split"));
    run(&straight, &[]);
    run(&split, &["--stop-at", "3"]);
    let e = fails(&[
        "train",
        "--out",
        s(&split),
        "--resume",
        "--no-progress",
        "--streams",
        "3",
    ]);
    assert!(e.contains("WebDataset streaming"), "{e}");
    run(&split, &["--resume"]);
    assert_eq!(loss_columns(&straight).len(), 7);
    assert_eq!(loss_columns(&straight), loss_columns(&split));
}

/// An export made with `--splits train=0.6,val=0.4`: `train --data DIR:webdataset` trains on
/// the train split (and says so), stores it in the run's config and refuses a resume on
/// another; `:NAME` picks a split, an unknown one is an error listing the splits; `eval` takes
/// `val` by default (the ids it reports are val's) and `:train` when named; an export without
/// `train` but with two splits asks which.
#[test]
fn webdataset_splits_train_on_train_and_evaluate_on_val() {
    use stereo_io::StereoDataset;
    let dir = tempfile::tempdir().unwrap();
    let (synth, shards) = (synth_five(dir.path()), dir.path().join("shards"));
    let export = |out: &Path, splits: &str| {
        stereo_io::export_webdataset(
            &synth,
            out,
            None,
            &stereo_io::ReadOptions::default(),
            &stereo_io::WebDatasetOptions {
                shuffle_seed: 4,
                splits: stereo_io::parse_splits(splits).unwrap(),
                ..Default::default()
            },
        )
        .unwrap()
    };
    export(&shards, "train=0.6,val=0.4");
    let ids = |split: &str| -> Vec<String> {
        let ds = stereo_io::WebDataset::open_splits(&shards, &[split]).unwrap();
        let mut v: Vec<String> = (0..ds.len()).map(|i| ds.id(i).unwrap().into()).collect();
        v.sort();
        v
    };
    let (train, val) = (ids("train"), ids("val"));
    assert_eq!((train.len(), val.len()), (3, 2));

    let data = format!("{}:webdataset", s(&shards));
    let run = dir.path().join("run");
    let mut args = vec!["train", "--data", &data, "--out", s(&run), "--steps", "2"];
    args.extend(short_run::TINY_TRAINING);
    let text = ok_logged(&args);
    assert!(
        text.contains(&format!(
            "{} (webdataset split train, 3 samples)",
            s(&shards)
        )),
        "{text}"
    );
    let stored = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(stored.contains("splits = [\"train\"]"), "{stored}");
    // Naming the split it chose is the same run; another split is not.
    let train_named = format!("{data}:train");
    let resume = ["--out", s(&run), "--resume", "--no-progress"];
    ok(&[&["train", "--data", &train_named][..], &resume].concat());
    let val_named = format!("{data}:val");
    let e = fails(&[&["train", "--data", &val_named][..], &resume].concat());
    assert!(e.contains("WebDataset splits included"), "{e}");

    let val_run = dir.path().join("val_run");
    let mut args = vec![
        "train",
        "--data",
        &val_named,
        "--out",
        s(&val_run),
        "--steps",
        "1",
    ];
    args.extend(short_run::TINY_TRAINING);
    let text = ok_logged(&args);
    assert!(text.contains("(webdataset split val, 2 samples)"), "{text}");
    let unknown = format!("{data}:tset");
    let e = fails(&[
        "train",
        "--data",
        &unknown,
        "--out",
        s(&dir.path().join("r2")),
        "--steps",
        "1",
    ]);
    assert!(
        e.contains("no split \"tset\"") && e.contains("its splits: train, val"),
        "{e}"
    );

    // Evaluation: `val` by default, the split named otherwise; the report's ids are its own.
    let eval_ids = |spec: &str| -> Vec<String> {
        let json = dir.path().join("eval.json");
        let text = ok_logged(&short_eval(spec, &run, &json));
        assert!(text.contains("webdataset split"), "{text}");
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        let mut v: Vec<String> = report["per_image"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["id"].as_str().unwrap().to_string())
            .collect();
        v.sort();
        v
    };
    assert_eq!(eval_ids(&data), val);
    assert_eq!(eval_ids(s(&shards)), val);
    assert_eq!(eval_ids(&train_named), train);

    // No `train` and two splits: train asks which rather than mixing them.
    let ab = dir.path().join("ab");
    export(&ab, "a=0.5,b=0.5");
    let e = fails(&[
        "train",
        "--data",
        s(&ab),
        "--out",
        s(&dir.path().join("r3")),
        "--steps",
        "1",
    ]);
    assert!(
        e.contains("splits a, b and no `train` split") && e.contains("DIR:webdataset:SPLIT"),
        "{e}"
    );
}
