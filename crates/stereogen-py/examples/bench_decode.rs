//! Decode throughput of one 1920×1080 stereo sample (two 8-bit PNG + two float32 EXR with a
//! validity channel), side by side: Rust (`stereo_io`), Python through the `stereogen` module, and
//! Python through Pillow + OpenEXR.
//!
//! `cargo run --release -p stereogen-py --example bench_decode [-- REPEATS [--rust-only]]`
//!
//! Builds the module with maturin into a venv under $STEREOGEN_HOME/python (pinned maturin,
//! numpy, OpenEXR, Pillow from PyPI) on first use. Prints a table and the ratios.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use stereo_io::*;

use pinned_venv::{ensure_venv, run};
use test_support::{pinned_venv, python_envs::install_stereogen_module};

const PINS: &[&str] = &[
    "maturin==1.16.0",
    "numpy==2.4.6",
    "OpenEXR==3.4.3",
    "Pillow==12.0.0",
];
const W: usize = 1920;
const H: usize = 1080;

/// A photo-like picture (smooth shading, edges, grain) so PNG compresses as it does on renders.
fn picture(seed: u32) -> RgbImage {
    let mut data = Vec::with_capacity(W * H * 3);
    let mut state = seed.wrapping_mul(2_654_435_761).max(1);
    for y in 0..H {
        for x in 0..W {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            let grain = (state % 9) as f32 - 4.0;
            let (fx, fy) = (x as f32 / W as f32, y as f32 / H as f32);
            let blob =
                (((fx * 7.0 + seed as f32).sin() * (fy * 5.0).cos()) > 0.2) as u8 as f32 * 60.0;
            for c in 0..3 {
                let v = 40.0 + 120.0 * fx * (c as f32 + 1.0) / 3.0 + 50.0 * fy + blob + grain;
                data.push(v.clamp(0.0, 255.0) as u8);
            }
        }
    }
    RgbImage {
        width: W,
        height: H,
        data,
    }
}

/// Smooth disparity with planar pieces and ~8% invalid background, like a render.
fn disparity(shift: f32) -> DisparityMap {
    let mut m = DisparityMap::new(W, H);
    for y in 0..H {
        for x in 0..W {
            let i = y * W + x;
            let (fx, fy) = (x as f32 / W as f32, y as f32 / H as f32);
            if fy < 0.08 {
                continue;
            }
            m.valid[i] = true;
            m.data[i] =
                shift + 4.0 + 60.0 * fy + 25.0 * ((fx * 9.0).sin() * (fy * 4.0).cos()).max(0.0);
        }
    }
    m
}

fn write_sample(root: &Path) {
    let layout = DatasetLayout::new(root);
    let files = layout.sample_paths("bench", "0000000");
    std::fs::create_dir_all(root.join("bench")).unwrap();
    write_png_rgb(&layout.abs(&files.left), &picture(1)).unwrap();
    write_png_rgb(&layout.abs(&files.right), &picture(2)).unwrap();
    let meta = DisparityMeta {
        f_px: Some(1500.0),
        baseline_m: Some(0.1),
        view: None,
    };
    write_disparity_exr(&layout.abs(&files.disp_left), &disparity(0.0), &meta).unwrap();
    write_disparity_exr(&layout.abs(&files.disp_right), &disparity(0.5), &meta).unwrap();
    let entry = serde_json::json!({
        "id": "0000000", "category": "bench", "index": 0, "files": files,
        "width": W, "height": H, "f_px": 1500.0, "baseline_m": 0.1, "cx": W as f64 / 2.0, "cy": H as f64 / 2.0,
    });
    let entry: ManifestEntry = serde_json::from_value(entry).unwrap();
    Manifest::open(&layout.manifest())
        .unwrap()
        .0
        .append(&entry)
        .unwrap();
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(10);
    let dir = tempfile::tempdir().unwrap();
    write_sample(dir.path());
    let bytes: u64 = walkdir(dir.path())
        .iter()
        .map(|p| std::fs::metadata(p).unwrap().len())
        .sum();

    let ds = open_dataset(dir.path(), None).unwrap();
    let time_rust = |n: usize| -> Vec<f64> {
        (0..n)
            .map(|_| {
                let t0 = Instant::now();
                let s = ds.sample(0).unwrap();
                assert_eq!(s.left.width, W);
                t0.elapsed().as_secs_f64()
            })
            .collect()
    };
    let mut times = time_rust(repeats);
    let stats = |t: &mut Vec<f64>| {
        t.sort_by(f64::total_cmp);
        (t[0], t[t.len() / 2])
    };
    let (rust_min, rust_med) = stats(&mut times.clone());
    if std::env::args().any(|a| a == "--rust-only") {
        println!(
            "Rust stereo_io: best {:.1} ms, median {:.1} ms",
            rust_min * 1e3,
            rust_med * 1e3
        );
        let best_of = |f: &dyn Fn()| {
            (0..repeats)
                .map(|_| {
                    let t = Instant::now();
                    f();
                    t.elapsed().as_secs_f64()
                })
                .fold(f64::INFINITY, f64::min)
        };
        let cat = dir.path().join("bench");
        println!(
            "  one PNG, serial: {:.1} ms",
            1e3 * best_of(&|| {
                read_rgb(&cat.join("0000000_left.png")).unwrap();
            })
        );
        println!(
            "  one EXR, serial: {:.1} ms",
            1e3 * best_of(&|| {
                read_disparity_exr(&cat.join("0000000_left.disp.exr")).unwrap();
            })
        );
        return;
    }
    let venv = ensure_venv("venv-bench", PINS);
    install_stereogen_module(&venv);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench/bench_decode.py");
    let out = run(
        Command::new(venv.join("bin/python"))
            .arg(script)
            .arg(dir.path())
            .arg(repeats.to_string()),
        "bench_decode.py",
    );
    // Rust again after Python: half the runs on each side of it, against load drift.
    times.extend(time_rust(repeats));
    let (rust_min, rust_med) = stats(&mut times);
    let py: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    let f = |k: &str| py[k].as_f64().unwrap();
    let decoded_mb = (W * H * (3 + 3 + 4 + 1 + 4 + 1)) as f64 / 1e6;
    println!(
        "One {W}x{H} sample: 2 PNG + 2 EXR, {:.1} MB on disk, {decoded_mb:.1} MB decoded; best / median of {repeats} (Rust: {repeats} before and {repeats} after Python), {} cores",
        bytes as f64 / 1e6,
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!(
        "{:<34} {:>9} {:>9} {:>11}",
        "decoder", "best ms", "median ms", "samples/s"
    );
    for (name, min, med) in [
        ("Rust stereo_io", rust_min, rust_med),
        (
            "Python stereogen module",
            f("stereogen_min"),
            f("stereogen_median"),
        ),
        (
            "Python Pillow + OpenEXR",
            f("pillow_openexr_min"),
            f("pillow_openexr_median"),
        ),
    ] {
        println!(
            "{name:<34} {:>9.1} {:>9.1} {:>11.2}",
            min * 1e3,
            med * 1e3,
            1.0 / med
        );
    }
    println!(
        "ratio Pillow+OpenEXR / stereogen module (median): {:.2}x",
        f("pillow_openexr_median") / f("stereogen_median")
    );
    println!(
        "ratio stereogen module / Rust (median): {:.2}x",
        f("stereogen_median") / rust_med
    );
}

fn walkdir(dir: &Path) -> Vec<PathBuf> {
    let mut out = vec![];
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walkdir(&p))
        } else {
            out.push(p)
        }
    }
    out
}
