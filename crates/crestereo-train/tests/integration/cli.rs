//! The `crestereo infer` command on the fixture PNGs, and its error messages.

// The model crate's fixture helpers, not a second copy of them.
use crate::network_fixtures;
use std::path::Path;
use std::process::Command;

use network_fixtures::*;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_crestereo"))
}

#[test]
fn infer_cli_matches_reference_two_pass() {
    let dir = tempfile::tempdir().unwrap();
    let e = fixtures().join("eval_cascade_1x128x192");
    let out = dir.path().join("disp.exr");
    let pfm = dir.path().join("disp.pfm");
    let viz = dir.path().join("disp.png");
    let status = bin()
        .arg("infer")
        .arg(e.join("left.png"))
        .arg(e.join("right.png"))
        .arg("-o")
        .arg(&out)
        .arg("--pfm")
        .arg(&pfm)
        .arg("--viz")
        .arg(&viz)
        .arg("--weights")
        .arg(fixtures().join("weights_seed0.pt"))
        .args(["--iters", "20", "--stages", "2"])
        .status()
        .unwrap();
    assert!(status.success());
    let (w, h, data) = read_exr(&out).unwrap();
    assert_eq!((w, h), (192, 128));
    let reference = npy("eval_cascade_1x128x192/pred_full.npy");
    let (err, _) = max_err(&data, &reference.data[..128 * 192]);
    println!("CLI disparity vs pred_full[:, 0]: max|err| {err:.3e}");
    assert!(err <= 1e-3, "CLI error {err}");
    // PFM: bottom-to-top rows, same values
    let bytes = std::fs::read(&pfm).unwrap();
    let header = b"Pf\n192 128\n-1.0\n";
    assert_eq!(&bytes[..header.len()], header);
    let body: Vec<f32> = bytes[header.len()..]
        .chunks(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(body.len(), 192 * 128);
    assert_eq!(body[0], data[127 * 192]);
    let png = image::open(&viz).unwrap();
    assert!(png.width() > 192 && png.height() >= 128);
}

fn run_err(args: &[&std::ffi::OsStr]) -> String {
    let out = bin().args(args).output().unwrap();
    assert!(!out.status.success(), "expected failure");
    String::from_utf8_lossy(&out.stderr).to_string()
}

#[test]
fn infer_cli_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let e = fixtures().join("eval_cascade_1x128x192");
    let weights = fixtures().join("weights_seed0.pt");
    let out = dir.path().join("o.exr");
    let infer_err = |left: &Path, right: &Path, out: &Path, weights: &Path| {
        run_err(&[
            "infer".as_ref(),
            left.as_os_str(),
            right.as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
            "--weights".as_ref(),
            weights.as_os_str(),
        ])
    };
    // mismatched sizes
    let small = dir.path().join("small.png");
    image::RgbImage::new(64, 32).save(&small).unwrap();
    let msg = infer_err(&e.join("left.png"), &small, &out, &weights);
    assert!(msg.contains("192x128") && msg.contains("64x32"), "{msg}");
    // unreadable image
    let bogus = dir.path().join("bogus.png");
    std::fs::write(&bogus, b"not an image").unwrap();
    let msg = infer_err(&bogus, &e.join("right.png"), &out, &weights);
    assert!(
        msg.contains("cannot read image") && msg.contains("bogus.png"),
        "{msg}"
    );
    // missing weights file
    let missing = dir.path().join("none.pt");
    let msg = infer_err(&e.join("left.png"), &e.join("right.png"), &out, &missing);
    assert!(msg.contains("does not exist"), "{msg}");
    // a file that is not weights is named as such, not as a missing file
    let msg = infer_err(&e.join("left.png"), &e.join("right.png"), &out, &bogus);
    assert!(
        msg.contains("bogus.png") && msg.contains("is not a Burn record"),
        "{msg}"
    );
    // an output folder that does not exist is refused before the images are read
    let nowhere = dir.path().join("nowhere").join("disp.exr");
    let msg = infer_err(&bogus, &e.join("right.png"), &nowhere, &weights);
    assert!(
        msg.contains("nowhere") && msg.contains("does not exist") && !msg.contains("bogus"),
        "{msg}"
    );
}

#[test]
fn infer_cli_stages_and_padding() {
    let dir = tempfile::tempdir().unwrap();
    let e = fixtures().join("eval_cascade_1x128x192");
    let weights = fixtures().join("weights_seed0.pt");
    let run = |left: &Path, right: &Path, stages: &str, out: &Path| {
        let status = bin()
            .arg("infer")
            .arg(left)
            .arg(right)
            .arg("-o")
            .arg(out)
            .arg("--weights")
            .arg(&weights)
            .args(["--stages", stages])
            .status()
            .unwrap();
        assert!(status.success());
        read_exr(out).unwrap()
    };
    // one stage = a single full-resolution pass without initialisation
    let (w, h, single) = run(
        &e.join("left.png"),
        &e.join("right.png"),
        "1",
        &dir.path().join("s1.exr"),
    );
    assert_eq!((w, h), (192, 128));
    let reference = npy("eval_cascade_1x128x192/pred_single_pass_no_init.npy");
    let (err, _) = max_err(&single, &reference.data[..128 * 192]);
    println!("--stages 1 vs pred_single_pass_no_init: max|err| {err:.3e}");
    assert!(err <= 1e-3);
    // a size that is no multiple of 64 with three stages: padded, run, cropped back
    let crop = |src: &Path, dst: &Path| {
        image::open(src)
            .unwrap()
            .crop_imm(0, 0, 150, 100)
            .save(dst)
            .unwrap();
    };
    let (l, r) = (dir.path().join("l.png"), dir.path().join("r.png"));
    crop(&e.join("left.png"), &l);
    crop(&e.join("right.png"), &r);
    let (w, h, three) = run(&l, &r, "3", &dir.path().join("s3.exr"));
    assert_eq!((w, h), (150, 100));
    assert!(three.iter().all(|v| v.is_finite()));
}

/// The number before `unit` in `line` (`"12.5 samples/s"` → 12.5).
fn number_before(line: &str, unit: &str) -> f64 {
    let head = line
        .split(unit)
        .next()
        .filter(|h| h.len() < line.len())
        .unwrap_or_else(|| panic!("no `{unit}` in: {line}"));
    let word = head.split_whitespace().last().unwrap_or("");
    word.parse()
        .unwrap_or_else(|_| panic!("`{word}` before `{unit}` is no number in: {line}"))
}

#[test]
fn bench_loader_prints_a_rate_per_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let synth = bin()
        .args(["synth", "--count", "3", "--size", "96x160", "--out"])
        .arg(&data)
        .output()
        .unwrap();
    assert!(synth.status.success(), "{synth:?}");
    let out = test_support::run_ok(
        bin()
            .args(["bench", "--what", "loader", "--loader-threads", "2,1,2"])
            .args(["--samples", "3", "--data"])
            .arg(format!("{}:crestereo", data.display()))
            .env("CRESTEREO_LOG", "warn"),
    );
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    println!("{text}");
    assert!(text.contains("crop 384x512"), "{text}");
    let lines: Vec<&str> = text.lines().filter(|l| l.starts_with("threads ")).collect();
    // one line per distinct thread count, ascending
    let threads: Vec<f64> = lines.iter().map(|l| number_before(l, ":")).collect();
    assert_eq!(threads, [1.0, 2.0], "{text}");
    for line in &lines {
        let rate = number_before(line, " samples/s");
        let ms = number_before(line, " ms/sample");
        let steps = number_before(line, "/s, prefetch");
        assert!(rate.is_finite() && rate > 0.0, "{line}");
        assert!(ms.is_finite() && ms > 0.0, "{line}");
        assert!((rate * ms / 1000.0 - 1.0).abs() < 0.02, "{line}");
        assert!((steps * 8.0 / rate - 1.0).abs() < 0.02, "{line}");
    }
    let collate = text
        .lines()
        .find(|l| l.starts_with("collate batch 8"))
        .unwrap_or_else(|| panic!("no collate line in:\n{text}"));
    let ms = number_before(collate, " ms (median");
    assert!(ms.is_finite() && ms > 0.0, "{collate}");
    // --data is required, and a thread count of 0 is refused
    let out = bin().args(["bench", "--what", "loader"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--data"));
    let out = bin()
        .args(["bench", "--what", "loader", "--loader-threads", "0"])
        .arg("--data")
        .arg(&data)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--loader-threads"));
}

/// `CRESTEREO_ISA` picks the copy of the vector kernels `bench` reports (and runs), and a name
/// it does not know is refused before any work, with the names it takes.
#[test]
fn kernel_instruction_set_is_named_and_checked() {
    let out = bin()
        .args([
            "bench",
            "--what",
            "infer",
            "--infer-size",
            "64,64",
            "--threads",
            "1",
        ])
        .env("CRESTEREO_ISA", "portable")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("cpu: "))
        .expect("a cpu line");
    assert!(
        line.contains("kernels portable (best here ") && line.contains("gemm "),
        "{line}"
    );
    assert!(stdout.contains("inference (1x64x64"), "{stdout}");

    let out = bin()
        .args(["bench", "--what", "infer", "--infer-size", "64,64"])
        .env("CRESTEREO_ISA", "avx1024")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty(), "nothing runs: {:?}", out.stdout);
    assert!(
        stderr.contains("CRESTEREO_ISA=\"avx1024\": expected one of portable, avx2, avx512"),
        "{stderr}"
    );
}

/// `crestereo score` writes, per sample, exactly the metrics `crestereo eval` reports for it (one
/// function computes both), continues a file a kill left behind (the samples it holds are kept,
/// a torn last line is cut off), and refuses to mix in scores of other options.
#[test]
fn score_equals_eval_per_image_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    crestereo_train::synthetic::write_crestereo_dataset(&data, 4, 128, 64, 0).unwrap();
    let weights = fixtures().join("weights_seed0.pt");
    let opts = ["--iters", "2", "--stages", "1"];
    let eval_json = dir.path().join("eval.json");
    let o = bin()
        .arg("eval")
        .arg("--data")
        .arg(&data)
        .arg("--weights")
        .arg(&weights)
        .args(opts)
        .arg("--json")
        .arg(&eval_json)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&eval_json).unwrap()).unwrap();
    let scores = dir.path().join("scores.jsonl");
    let score = |extra: &[&str]| {
        bin()
            .arg("score")
            .arg(&data)
            .arg("--weights")
            .arg(&weights)
            .arg("--out")
            .arg(&scores)
            .args(extra)
            .output()
            .unwrap()
    };
    // Two samples, then a kill in the middle of the third one's line.
    let o = score(&["--iters", "2", "--stages", "1", "--limit", "2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&scores)
        .unwrap();
    std::io::Write::write_all(&mut f, br#"{"index":2,"id":"torn"#).unwrap();
    drop(f);
    let o = score(&opts);
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{said}");
    assert!(
        said.contains("scored 2 sample(s)") && said.contains("(2 already in"),
        "{said}"
    );
    let text = std::fs::read_to_string(&scores).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines[0]["scores"], "crestereo-scores");
    assert_eq!(lines.len(), 5, "{text}");
    let per_image = report["per_image"].as_array().unwrap();
    assert_eq!(per_image.len(), 4);
    for (i, line) in lines[1..].iter().enumerate() {
        assert_eq!(line["index"], i, "{text}");
        let evaluated = per_image.iter().find(|r| r["id"] == line["id"]).unwrap();
        for key in ["width", "height", "all", "nonocc", "nonocc_source"] {
            assert_eq!(line[key], evaluated[key], "sample {i}, {key}");
        }
        assert!(line["all"]["epe"].as_f64().unwrap() > 0.0);
    }
    // Other options are not mixed into the same file.
    let o = score(&["--iters", "3", "--stages", "1"]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("holds scores made otherwise"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn eval_disturb_level_zero_equals_plain_eval_and_levels_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    crestereo_train::synthetic::write_crestereo_dataset(&data, 2, 128, 64, 0).unwrap();
    let weights = fixtures().join("weights_seed0.pt");
    let eval = |json: &Path, extra: &[&str]| {
        bin()
            .arg("eval")
            .arg("--data")
            .arg(&data)
            .arg("--weights")
            .arg(&weights)
            .args(["--iters", "2", "--stages", "1", "--json"])
            .arg(json)
            .args(extra)
            .output()
            .unwrap()
    };
    let read = |p: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    let plain_json = dir.path().join("plain.json");
    let o = eval(&plain_json, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plain = read(&plain_json);
    assert!(plain.get("disturbed").is_none());

    let json = dir.path().join("d.json");
    let o = eval(
        &json,
        &[
            "--disturb",
            "blur:0",
            "--disturb",
            "vshift:0,2",
            "--disturb",
            "noise:5",
            "--disturb-seed",
            "4",
        ],
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("right view disturbed"), "{stdout}");
    let d = read(&json);
    // The undisturbed pass of a --disturb run is the plain evaluation.
    assert_eq!(d["mean_all"], plain["mean_all"]);
    assert_eq!(d["mean_nonocc"], plain["mean_nonocc"]);
    let rows = d["disturbed"].as_array().unwrap();
    let kinds: Vec<(String, f64)> = rows
        .iter()
        .map(|r| {
            (
                r["kind"].as_str().unwrap().to_string(),
                r["level"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        kinds,
        [
            ("blur".to_string(), 0.0),
            ("vshift".to_string(), 0.0),
            ("vshift".to_string(), 2.0),
            ("noise".to_string(), 5.0)
        ]
    );
    // Level 0 goes through the disturbance path and equals the plain evaluation exactly.
    for r in &rows[..2] {
        assert_eq!(r["mean_all"], plain["mean_all"], "{r}");
        assert_eq!(r["mean_nonocc"], plain["mean_nonocc"], "{r}");
        assert_eq!(r["images"], 2);
    }
    assert_ne!(rows[2]["mean_all"], plain["mean_all"]);
    assert_ne!(rows[3]["mean_all"], plain["mean_all"]);
    let csv = std::fs::read_to_string(dir.path().join("d.disturb.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 5, "{csv}");
    assert!(lines[0].starts_with("kind,level,unit,seed,images,failed,epe,"));
    assert!(lines[3].starts_with("vshift,2,px,4,2,0,"), "{csv}");
    let png = stereo_io::read_image(&dir.path().join("d.disturb.png")).unwrap();
    assert_eq!((png.width, png.height), (3 * 420, 340));

    // The same seed repeats the noise exactly; another seed draws other noise.
    let again = dir.path().join("again.json");
    let o = eval(&again, &["--disturb", "noise:5", "--disturb-seed", "4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        read(&again)["disturbed"][0]["mean_all"],
        rows[3]["mean_all"]
    );
    let o = eval(&again, &["--disturb", "noise:5", "--disturb-seed", "5"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_ne!(
        read(&again)["disturbed"][0]["mean_all"],
        rows[3]["mean_all"]
    );

    // A wrong kind is refused before any image is read.
    let bad = dir.path().join("bad.json");
    let o = eval(&bad, &["--disturb", "fog:1"]);
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(said.contains("`fog` is not a disturbance"), "{said}");
    assert!(!bad.exists());
}
