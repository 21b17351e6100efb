//! `crestereo export pytorch`: the state dict it writes reads back into Burn bit for bit, PyTorch
//! itself loads it (`torch.load(weights_only=True)`, `load_state_dict(strict=True)`) into the
//! reference model of `crates/crestereo/bench/torch_reference.py`, which then predicts what
//! `crestereo infer` predicts; and bad input gets one clear line and no file.

// The model crate's fixture helpers, not a second copy of them.
use crate::network_fixtures;
use crate::pinned_venv;
use crate::short_run;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Instant;
use test_support::output_text;

use crestereo::weights::{NamedArray, load_weights, named_parameters};
use crestereo::{CREStereo, CREStereoConfig, CpuBackend};
use network_fixtures::{fixtures, read_exr};

/// PyTorch and NumPy of the check (numpy as in the other Python checks of the workspace).
const TORCH_PINS: &[&str] = &["torch==2.15.0", "numpy==2.4.6"];
/// The largest |PyTorch − Burn| disparity allowed on the fixture pair, in pixels.
const TOLERANCE_PX: f32 = 1e-4;

fn crestereo(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_crestereo"))
        .args(args)
        .env("CRESTEREO_LOG", "warn")
        .env_remove("CRESTEREO_WEIGHTS")
        .output()
        .unwrap()
}

fn ok(args: &[&std::ffi::OsStr]) -> String {
    let out = crestereo(args);
    let text = output_text(&out);
    assert!(out.status.success(), "crestereo {args:?} failed:\n{text}");
    text
}

fn os<S: AsRef<std::ffi::OsStr> + ?Sized>(s: &S) -> &std::ffi::OsStr {
    s.as_ref()
}

/// `crestereo export pytorch --weights W -o OUT`; returns what it printed.
fn export(weights: &Path, out: &Path) -> String {
    let text = ok(&[
        os("export"),
        os("pytorch"),
        os("--weights"),
        os(weights),
        os("-o"),
        os(out),
    ]);
    assert!(
        text.contains("94 tensors") && text.contains(&*out.to_string_lossy()),
        "{text}"
    );
    text
}

fn load(weights: &Path) -> CREStereo<CpuBackend> {
    let device = Default::default();
    load_weights(
        CREStereoConfig::new().init::<CpuBackend>(&device),
        weights,
        &device,
    )
    .unwrap()
}

/// Every parameter of `a` and `b` has the same name, shape and bits.
fn assert_bit_identical(a: &[NamedArray], b: &[NamedArray], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: tensor count");
    for (x, y) in a.iter().zip(b) {
        assert_eq!((&x.name, &x.shape), (&y.name, &y.shape), "{what}");
        let differ = x
            .data
            .iter()
            .zip(&y.data)
            .filter(|(p, q)| p.to_bits() != q.to_bits())
            .count();
        assert_eq!(differ, 0, "{what}: {} differs in {differ} values", x.name);
    }
}

/// The reference key list (`state_dict_keys.txt`: key, shape, count).
fn reference_keys() -> Vec<(String, Vec<usize>)> {
    std::fs::read_to_string(fixtures().join("state_dict_keys.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let mut f = l.split('\t');
            let key = f.next().unwrap().to_string();
            let shape = f
                .next()
                .unwrap()
                .trim_matches(|c| c == '(' || c == ')')
                .split(',')
                .filter_map(|d| d.trim().parse().ok())
                .collect();
            (key, shape)
        })
        .collect()
}

/// Burn → .pth → Burn: `original` (any weights `crestereo` reads) exported to `pth` loads back
/// into a model whose every parameter has the bits of the original's; the keys and shapes are
/// the reference's, in its order.
fn check_round_trip(original: &Path, pth: &Path, what: &str) {
    let before = named_parameters(&load(original));
    let after = named_parameters(&load(pth));
    assert_bit_identical(&before, &after, what);
    let keys: Vec<(String, Vec<usize>)> = after
        .iter()
        .map(|t| (t.name.clone(), t.shape.clone()))
        .collect();
    assert_eq!(keys, reference_keys(), "{what}: keys and shapes");
    let values: usize = after.iter().map(|t| t.data.len()).sum();
    assert_eq!(values, crestereo::weights::REFERENCE_PARAM_COUNT);
    println!(
        "{what}: round trip through {} bit-identical on all {} tensors ({values} values)",
        pth.display(),
        after.len()
    );
}

/// Loads `pth` in PyTorch (`weights_only=True`, plain and memory-mapped), checks the keys
/// against the reference list (and, given `same_as`, every tensor against that file's with
/// `torch.equal`), loads it into the reference model with `strict=True`, runs the reference
/// two-pass procedure (20 iterations) on the fixture pair and compares with `crestereo infer
/// --weights pth` on the same pair. Returns max |PyTorch − Burn| in pixels.
fn check_in_pytorch(pth: &Path, same_as: Option<&Path>, work: &Path, what: &str) -> f32 {
    let t0 = Instant::now();
    let venv = pinned_venv::ensure_venv("venv-torch", TORCH_PINS);
    println!(
        "{what}: PyTorch venv ready in {:.1}s ({})",
        t0.elapsed().as_secs_f64(),
        venv.display()
    );
    let pair = fixtures().join("eval_cascade_1x128x192");
    let torch_pred = work.join("torch_pred.npy");
    let script = work.join("check_pth.py");
    std::fs::write(&script, CHECK_PY).unwrap();
    let t0 = Instant::now();
    let stdout = pinned_venv::run(
        Command::new(venv.join("bin/python"))
            .arg(&script)
            .arg(pth)
            .arg(same_as.map_or_else(|| "-".into(), |p| p.as_os_str().to_owned()))
            .arg(fixtures().join("state_dict_keys.txt"))
            .arg(&pair)
            .arg(&torch_pred)
            .env(
                "PYTHONPATH",
                Path::new(env!("CARGO_MANIFEST_DIR")).join("../crestereo/bench"),
            ),
        "PyTorch check",
    );
    println!(
        "{what}: {} ({:.1}s)",
        stdout.trim(),
        t0.elapsed().as_secs_f64()
    );
    let torch = stereo_io::read_npy(&torch_pred).unwrap();
    assert_eq!(torch.shape, vec![128, 192]);

    let burn_out = work.join("burn_disp.exr");
    ok(&[
        os("infer"),
        os(&pair.join("left.png")),
        os(&pair.join("right.png")),
        os("-o"),
        os(&burn_out),
        os("--weights"),
        os(pth),
        os("--iters"),
        os("20"),
        os("--stages"),
        os("2"),
    ]);
    let (w, h, burn) = read_exr(&burn_out).unwrap();
    assert_eq!((w, h), (192, 128));
    let (diff, largest) = network_fixtures::max_err(&burn, &torch.data);
    println!("{what}: max |PyTorch - Burn| = {diff:.3e} px (largest |disparity| {largest:.2} px)");
    assert!(
        diff <= TOLERANCE_PX,
        "{what}: PyTorch and crestereo infer differ by {diff:e} px"
    );
    diff
}

/// Run by the venv's Python: argv = pth, same_as ("-" for none), key list, pair folder, output.
const CHECK_PY: &str = r#"
import collections, io, sys, zipfile
import numpy as np
import torch
from torch_reference import CREStereo, resize

pth, same_as, keys_txt, pair, out = sys.argv[1:6]
torch.set_num_threads(1)  # the tests share 2 cores: more threads only contend
sd = torch.load(pth, weights_only=True)
assert type(sd) is collections.OrderedDict, type(sd)
keys = [l.split("\t")[0] for l in open(keys_txt).read().splitlines() if l.strip()]
assert list(sd.keys()) == keys, "keys differ from state_dict_keys.txt"
for k, v in sd.items():
    assert v.dtype == torch.float32 and v.is_contiguous() and v.device.type == "cpu", k
mapped = torch.load(pth, weights_only=True, mmap=True)
assert all(torch.equal(mapped[k], v) for k, v in sd.items()), "mmap load differs"
if same_as != "-":
    ref = torch.load(same_as, weights_only=True)
    assert ref.keys() == sd.keys()
    bad = [k for k in sd if not torch.equal(ref[k], sd[k])]
    assert not bad, f"tensors differ from {same_as}: {bad}"
# torch.save of what was loaded writes the same records: the pickle byte for byte, every
# storage and small record alike (all but the serialization id, which torch draws at random)
buf = io.BytesIO()
torch.save(sd, buf)
ours, theirs = zipfile.ZipFile(pth), zipfile.ZipFile(buf)
assert ours.namelist() == theirs.namelist(), (ours.namelist()[:6], theirs.namelist()[:6])
for n in ours.namelist():
    if not n.endswith("/.data/serialization_id"):
        assert ours.read(n) == theirs.read(n), f"{n} differs from torch.save's"
m = CREStereo()
m.load_state_dict(sd, strict=True)
m.eval()
left = torch.from_numpy(np.load(f"{pair}/left.npy")).float()
right = torch.from_numpy(np.load(f"{pair}/right.npy")).float()
h, w = left.shape[-2:]
with torch.inference_mode():
    # the reference test procedure: pass 1 on the pair downsampled x1/2, pass 2 at full size
    p = m(resize(left, (h // 2, w // 2)), resize(right, (h // 2, w // 2)), 20)[-1]
    pred = m(left, right, 20, flow_init=p)[-1]
np.save(out, pred[0, 0].numpy().astype(np.float32))
print(f"torch {torch.__version__}: records as torch.save writes them, "
      f"loaded {len(sd)} tensors with strict=True"
      + (", all equal to the original" if same_as != "-" else ""))
"#;

#[test]
fn reference_weights_export_round_trips_and_pytorch_agrees() {
    let dir = tempfile::tempdir().unwrap();
    let original = fixtures().join("weights_seed0.pt");
    let pth = dir.path().join("model.pth");
    let t0 = Instant::now();
    let text = export(&original, &pth);
    println!(
        "export of weights_seed0.pt: {:.2}s: {}",
        t0.elapsed().as_secs_f64(),
        text.trim()
    );
    check_round_trip(&original, &pth, "reference weights");

    // The same weights give the same bytes; an existing output needs --force.
    let first = std::fs::read(&pth).unwrap();
    let args = [
        os("export"),
        os("pytorch"),
        os("--weights"),
        os(&original),
        os("-o"),
        os(&pth),
    ];
    assert!(!crestereo(&args).status.success());
    ok(&[&args[..], &[os("--force")]].concat());
    assert!(
        std::fs::read(&pth).unwrap() == first,
        "export is not deterministic"
    );
    // A .pth exported from an export is the same file.
    let second = dir.path().join("again.pth");
    export(&pth, &second);
    assert!(std::fs::read(&second).unwrap() == first);

    check_in_pytorch(&pth, Some(&original), dir.path(), "reference weights");
}

#[test]
fn trained_checkpoint_export_round_trips_and_pytorch_agrees() {
    let dir = tempfile::tempdir().unwrap();
    let reference = fixtures().join("weights_seed0.pt");
    let run = short_run::fine_tune(dir.path(), &reference);
    let data = dir.path().join("data"); // the pairs fine_tune trained on
    let checkpoint = run.join("checkpoints/step-00000003/model.mpk");
    assert!(checkpoint.is_file());
    let changed = named_parameters(&load(&reference))
        .iter()
        .zip(&named_parameters(&load(&checkpoint)))
        .filter(|(a, b)| a.data != b.data)
        .count();
    println!("trained checkpoint: {changed} of 94 tensors changed in 3 steps");
    assert!(changed > 0, "training changed no weight");

    // The checkpoint directory, and the run directory for its newest checkpoint.
    let pth = dir.path().join("trained.pth");
    export(checkpoint.parent().unwrap(), &pth);
    let from_run = dir.path().join("from_run.pth");
    export(&run, &from_run);
    assert!(std::fs::read(&from_run).unwrap() == std::fs::read(&pth).unwrap());
    check_round_trip(&checkpoint, &pth, "trained checkpoint");
    // eval and train --init-weights read the .pth too.
    let json = dir.path().join("eval.json");
    ok(&[
        os("eval"),
        os("--data"),
        os(&data),
        os("--weights"),
        os(&pth),
        os("--iters"),
        os("2"),
        os("--stages"),
        os("1"),
        os("--limit"),
        os("1"),
        os("--json"),
        os(&json),
    ]);
    assert!(json.is_file());
    let run2 = dir.path().join("run2");
    let mut args = vec![
        os("train"),
        os("--data"),
        os(&data),
        os("--out"),
        os(&run2),
        os("--steps"),
        os("1"),
        os("--init-weights"),
        os(&pth),
    ];
    args.extend(short_run::TINY_TRAINING.iter().map(os));
    let text = ok(&args);
    assert!(text.contains("applied 94 tensors"), "{text}");

    check_in_pytorch(&pth, None, dir.path(), "trained checkpoint");
}

/// One line on stderr naming the problem, a failure exit, and no file left.
fn fails(args: &[std::ffi::OsString], dir: &Path, expect: &[&str]) {
    let args: Vec<&std::ffi::OsStr> = args.iter().map(os).collect();
    let before = listing(dir);
    let out = crestereo(&args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "crestereo {args:?} should fail");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line:\n{err}");
    for e in expect {
        assert!(err.contains(e), "{e:?} missing from: {err}");
    }
    assert_eq!(listing(dir), before, "files changed: {err}");
}

/// Every file below `dir` with its bytes.
fn listing(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let bytes = std::fs::read(&p).unwrap();
                v.push((p, bytes));
            }
        }
    }
    v.sort();
    v
}

#[test]
fn bad_input_gets_one_clear_line_and_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let weights = fixtures().join("weights_seed0.pt");
    let out = d.join("model.pth");
    let export = |w: Option<&Path>, o: &Path| {
        let mut v: Vec<std::ffi::OsString> = vec!["export".into(), "pytorch".into()];
        if let Some(w) = w {
            v.extend(["--weights".into(), w.into()]);
        }
        v.extend(["-o".into(), o.into()]);
        v
    };

    fails(&export(None, &out), d, &["no weights given", "--weights"]);
    let missing = d.join("none.pt");
    fails(
        &export(Some(&missing), &out),
        d,
        &["none.pt", "does not exist"],
    );
    fails(
        &export(Some(&d.join("none.mpk")), &out),
        d,
        &["none.mpk", "does not exist"],
    );
    fails(&export(Some(d), &out), d, &["holds no checkpoint"]);

    // Files that are not CREStereo weights.
    let junk_pt = d.join("junk.pt");
    std::fs::write(&junk_pt, b"not a state dict").unwrap();
    fails(
        &export(Some(&junk_pt), &out),
        d,
        &["junk.pt", "not CREStereo weights"],
    );
    let junk_mpk = d.join("junk.mpk");
    std::fs::write(&junk_mpk, b"not a record").unwrap();
    fails(
        &export(Some(&junk_mpk), &out),
        d,
        &["junk.mpk", "not CREStereo weights"],
    );
    // A well-formed state dict of another network, and one with a wrong shape.
    let other = d.join("other.pth");
    let tensor = |name: &str, shape: &[usize]| NamedArray {
        name: name.into(),
        shape: shape.to_vec(),
        data: vec![0.5; shape.iter().product()],
    };
    stereo_io::pth::write_state_dict(&[tensor("encoder.weight", &[4, 3])], &other).unwrap();
    fails(
        &export(Some(&other), &out),
        d,
        &["other.pth", "not CREStereo weights", "lack parameters"],
    );
    let mut shapes = named_parameters(&load(&weights));
    shapes[0] = tensor(&shapes[0].name.clone(), &[64, 3, 5, 5]);
    let misfit = d.join("misfit.pth");
    stereo_io::pth::write_state_dict(&shapes, &misfit).unwrap();
    fails(
        &export(Some(&misfit), &out),
        d,
        &["misfit.pth", "not CREStereo weights", "do not fit"],
    );

    // Outputs: missing folder, wrong extension, a folder, an existing file without --force.
    fails(
        &export(Some(&weights), &d.join("nowhere/model.pth")),
        d,
        &["nowhere", "does not exist"],
    );
    fails(
        &export(Some(&weights), &d.join("model.mpk")),
        d,
        &["model.mpk", ".pth or .pt"],
    );
    let folder = d.join("folder.pth");
    std::fs::create_dir(&folder).unwrap();
    fails(
        &export(Some(&weights), &folder),
        d,
        &["folder.pth", "folder"],
    );
    std::fs::write(&out, b"precious").unwrap();
    fails(
        &export(Some(&weights), &out),
        d,
        &["model.pth", "already exists", "--force"],
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"precious");
    // the output is checked before the weights are read
    fails(
        &export(Some(&missing), &out),
        d,
        &["model.pth", "already exists"],
    );
}
