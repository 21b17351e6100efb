//! `crestereo export onnx` checked by code nobody here wrote: ONNX's own checker
//! (`full_check=True`) and onnxruntime (CPU), in a test-managed venv, against `crestereo infer`
//! with the same weights — the reference fixture weights and a model after a few training steps,
//! on the fixture pair and on a random pair — and its refusals of bad input.

use crate::network_fixtures;
use crate::pinned_venv;
use crate::short_run;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crestereo::BgrImage;
use stereo_io::{NpyArray, RgbImage};

const PINS: &[&str] = &[
    "onnx==1.19.1",
    "onnxruntime==1.23.2",
    "numpy==2.4.6",
    "opencv-python-headless==5.0.0.93",
];

/// The bound of the issue: onnxruntime's disparity within 1e-4 px of Burn's.
const BOUND_PX: f32 = 1e-4;

fn crestereo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_crestereo"))
        .args(args)
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .expect("run crestereo")
}

fn ok(args: &[&str]) -> String {
    let o = crestereo(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "crestereo {args:?} failed:\n{err}");
    err
}

fn fails(args: &[&str]) -> String {
    let o = crestereo(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "crestereo {args:?} succeeded:\n{err}");
    err
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A pair as `crestereo infer` reads it (PNG) and as the graph takes it (the same pixels as
/// (1, 3, H, W) BGR arrays, made by the network's own image path).
struct Pair {
    left_png: PathBuf,
    right_png: PathBuf,
    left_npy: PathBuf,
    right_npy: PathBuf,
}

fn as_npy(png: &Path) -> PathBuf {
    let bgr = BgrImage::from_rgb(&stereo_io::read_rgb(png).unwrap());
    let out = png.with_extension("npy");
    let arr = NpyArray {
        shape: vec![1, 3, bgr.height, bgr.width],
        data: bgr.data,
    };
    stereo_io::write_npy(&out, &arr).unwrap();
    out
}

fn pair_from_pngs(dir: &Path, left: &Path, right: &Path) -> Pair {
    let (l, r) = (dir.join("left.png"), dir.join("right.png"));
    std::fs::copy(left, &l).unwrap();
    std::fs::copy(right, &r).unwrap();
    Pair {
        left_npy: as_npy(&l),
        right_npy: as_npy(&r),
        left_png: l,
        right_png: r,
    }
}

/// A random pair: smooth noise on the left, the right a shifted copy plus noise, so the network
/// has something to match.
fn random_pair(dir: &Path, h: usize, w: usize, seed: u64) -> Pair {
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 33) as u32
    };
    let base: Vec<u8> = (0..(h + 8) * (w + 16) * 3)
        .map(|_| (next() % 256) as u8)
        .collect();
    let view = |shift: usize, noise: &mut dyn FnMut() -> u32| RgbImage {
        width: w,
        height: h,
        data: (0..h * w * 3)
            .map(|i| {
                let (y, x, c) = (i / (3 * w), (i / 3) % w, i % 3);
                let v = base[((y + 4) * (w + 16) + x + shift) * 3 + c] as u32 + noise() % 9;
                v.min(255) as u8
            })
            .collect(),
    };
    let left = view(8, &mut next);
    let right = view(2, &mut next);
    let (l, r) = (
        dir.join(format!("rand{seed}_left.png")),
        dir.join(format!("rand{seed}_right.png")),
    );
    stereo_io::write_png_rgb(&l, &left).unwrap();
    stereo_io::write_png_rgb(&r, &right).unwrap();
    Pair {
        left_npy: as_npy(&l),
        right_npy: as_npy(&r),
        left_png: l,
        right_png: r,
    }
}

/// `crestereo infer` with `weights`: the disparity, row-major.
fn burn_disparity(weights: &Path, pair: &Pair, iters: &str, stages: &str, out: &Path) -> Vec<f32> {
    ok(&[
        "infer",
        s(&pair.left_png),
        s(&pair.right_png),
        "-o",
        s(out),
        "--weights",
        s(weights),
        "--iters",
        iters,
        "--stages",
        stages,
    ]);
    stereo_io::read_disparity(out, None).unwrap().0.data
}

/// Runs `bench/onnx_run.py --check` on `model` with `pairs`; returns its JSON report and each
/// pair's disparity.
fn onnxruntime(
    venv: &Path,
    model: &Path,
    pairs: &[(&Pair, PathBuf)],
) -> (serde_json::Value, Vec<Vec<f32>>) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../crestereo/bench/onnx_run.py");
    let mut cmd = Command::new(venv.join("bin/python"));
    cmd.arg(&script).arg(model).arg("--check");
    for (pair, out) in pairs {
        cmd.arg("--pair")
            .args([&pair.left_npy, &pair.right_npy, out]);
    }
    let report = pinned_venv::run(&mut cmd, "onnx_run.py");
    let report: serde_json::Value = serde_json::from_str(report.trim()).unwrap();
    let outputs = pairs
        .iter()
        .map(|(_, out)| stereo_io::read_npy(out).unwrap().data)
        .collect();
    (report, outputs)
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(
            0.0,
            |m, d| if d.is_nan() { f32::INFINITY } else { m.max(d) },
        )
}

/// Exports `weights` at `size`, runs the graph with onnxruntime on `pairs` and compares with
/// `crestereo infer`.
fn check_against_burn(
    venv: &Path,
    dir: &Path,
    label: &str,
    weights: &Path,
    size: &str,
    [iters, stages]: [&str; 2],
    pairs: &[&Pair],
) -> (PathBuf, Vec<Vec<f32>>) {
    let model = dir.join(format!("{label}.onnx"));
    let log = ok(&[
        "export",
        "onnx",
        "--weights",
        s(weights),
        "--size",
        size,
        "--iters",
        iters,
        "--stages",
        stages,
        "-o",
        s(&model),
    ]);
    println!("{label}: {}", log.trim());
    let runs: Vec<(&Pair, PathBuf)> = pairs
        .iter()
        .enumerate()
        .map(|(i, p)| (*p, dir.join(format!("{label}_ort_{i}.npy"))))
        .collect();
    let (report, ort) = onnxruntime(venv, &model, &runs);
    println!("{label}: onnx_run.py: {report}");
    assert_eq!(report["checker"], "passed (full_check=True)");
    assert_eq!(report["opset"], serde_json::json!([17]));
    assert_eq!(
        report["domains"],
        serde_json::json!([""]),
        "custom domains in the graph"
    );
    let ops: Vec<&str> = report["op_types"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(!ops.contains(&"Einsum"), "{ops:?}");
    assert!(ops.contains(&"GridSample"), "{ops:?}");
    let mut burns = Vec::new();
    for (i, pair) in pairs.iter().enumerate() {
        let burn = burn_disparity(
            weights,
            pair,
            iters,
            stages,
            &dir.join(format!("{label}_{i}.pfm")),
        );
        let diff = max_abs_diff(&ort[i], &burn);
        let range = burn.iter().fold(0f32, |m, v| m.max(v.abs()));
        println!(
            "{label}, pair {i}: max |onnxruntime − crestereo infer| = {diff:.3e} px (max |disparity| {range:.2})"
        );
        assert!(diff <= BOUND_PX, "{label}, pair {i}: {diff} px");
        burns.push(burn);
    }
    (model, burns)
}

/// The guide's onnxruntime block (docs/guide/deploy.md, after `<!-- run: onnx-snippet -->`), run
/// as a user would: in a folder holding `crestereo.onnx`, `left.png` and `right.png`. Returns its
/// `disparity.npy`.
fn run_readme_snippet(venv: &Path, dir: &Path, model: &Path, pair: &Pair) -> Vec<f32> {
    let page = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/guide/deploy.md");
    let readme = std::fs::read_to_string(&page).unwrap();
    let after = readme
        .split_once("<!-- run: onnx-snippet -->")
        .expect("the deploy page's onnx-snippet marker")
        .1;
    let code = after
        .split_once("```python\n")
        .and_then(|(_, rest)| rest.split_once("```"))
        .expect("a python block after the marker")
        .0;
    let work = dir.join("snippet");
    std::fs::create_dir_all(&work).unwrap();
    std::fs::copy(model, work.join("crestereo.onnx")).unwrap();
    std::fs::copy(&pair.left_png, work.join("left.png")).unwrap();
    std::fs::copy(&pair.right_png, work.join("right.png")).unwrap();
    std::fs::write(work.join("snippet.py"), code).unwrap();
    pinned_venv::run(
        Command::new(venv.join("bin/python"))
            .arg("snippet.py")
            .current_dir(&work),
        "the deploy page's onnxruntime snippet",
    );
    stereo_io::read_npy(&work.join("disparity.npy"))
        .unwrap()
        .data
}

#[test]
fn onnxruntime_matches_crestereo_infer_with_reference_and_trained_weights() {
    let venv = pinned_venv::ensure_venv("venv-onnx", PINS);
    let dir = tempfile::tempdir().unwrap();
    let fixtures = network_fixtures::fixtures();
    let e = fixtures.join("eval_cascade_1x128x192");
    let fixture = pair_from_pngs(dir.path(), &e.join("left.png"), &e.join("right.png"));
    let random = random_pair(dir.path(), 128, 192, 7);
    let reference = fixtures.join("weights_seed0.pt");
    let (model, burn) = check_against_burn(
        &venv,
        dir.path(),
        "reference",
        &reference,
        "128x192",
        ["20", "2"],
        &[&fixture, &random],
    );
    // One stage (a single full-resolution pass, no initialisation) and three (from a quarter of
    // the size): the other cascade loops the graph unrolls.
    let quarter = random_pair(dir.path(), 64, 128, 13);
    check_against_burn(
        &venv,
        dir.path(),
        "one_stage",
        &reference,
        "64x128",
        ["4", "1"],
        &[&quarter],
    );
    check_against_burn(
        &venv,
        dir.path(),
        "three_stages",
        &reference,
        "128x192",
        ["4", "3"],
        &[&random],
    );

    // The deploy page's five lines, images decoded by OpenCV.
    let snippet = run_readme_snippet(&venv, dir.path(), &model, &fixture);
    let diff = max_abs_diff(&snippet, &burn[0]);
    println!("deploy page snippet (cv2.imread + onnxruntime) vs crestereo infer: {diff:.3e} px");
    assert!(diff <= BOUND_PX, "deploy page snippet: {diff} px");

    // A model after a few training steps from the reference weights.
    let run = short_run::fine_tune(dir.path(), &reference);
    let small = random_pair(dir.path(), 64, 128, 11);
    check_against_burn(
        &venv,
        dir.path(),
        "trained",
        &run,
        "64x128",
        ["6", "2"],
        &[&small],
    );
}

/// `export onnx --weights W -o OUT` followed by `rest`.
fn export_args<'a>(weights: &'a str, out: &'a str, rest: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["export", "onnx", "--weights", weights, "-o", out];
    args.extend(rest);
    args
}

#[test]
fn bad_input_gets_one_line_and_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let weights = network_fixtures::fixtures().join("weights_seed0.pt");
    let w = s(&weights);
    let out = dir.path().join("m.onnx");
    let o = s(&out);
    let missing = dir.path().join("missing.pt");
    let garbage = dir.path().join("garbage.pt");
    std::fs::write(&garbage, b"not a state dict").unwrap();
    let nowhere = dir.path().join("nowhere/m.onnx");
    for (args, expect) in [
        (
            export_args(w, o, &["--size", "100x192"]),
            "not a multiple of 32",
        ),
        (export_args(w, o, &["--size", "32x64"]), "too small"),
        (
            export_args(w, o, &["--size", "128"]),
            "expected HEIGHTxWIDTH",
        ),
        (
            vec!["export", "onnx", "--size", "64x64", "-o", o],
            "no weights given",
        ),
        (
            export_args(s(&missing), o, &["--size", "64x64"]),
            "missing.pt",
        ),
        (
            export_args(s(&garbage), o, &["--size", "64x64"]),
            "garbage.pt",
        ),
        (
            export_args(w, s(&nowhere), &["--size", "64x64"]),
            "does not exist",
        ),
    ] {
        let err = fails(&args);
        assert!(err.contains(expect), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(!out.exists() && !nowhere.exists(), "{args:?} left a file");
    }
    std::fs::remove_file(&garbage).unwrap();

    // An existing output is kept, byte for byte, unless --force.
    std::fs::write(&out, b"keep me").unwrap();
    let err = fails(&export_args(w, o, &["--size", "64x64", "--iters", "1"]));
    assert!(err.contains("--force"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"keep me");
    ok(&export_args(
        w,
        o,
        &["--size", "64x64", "--iters", "2", "--force"],
    ));
    // Two iterations use every module: all 5.4 M parameters (21.7 MB) are initializers.
    assert!(
        std::fs::metadata(&out).unwrap().len() > 21_700_000,
        "the graph holds the weights"
    );
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n != "m.onnx")
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}
