//! Builds the `stereogen` Python module with maturin into a cached venv and runs its pytest
//! suite (crates/stereogen-py/pytests) against fixtures whose Rust readings are saved as .npy.
//!
//! The venv lives under $STEREOGEN_HOME/python (pinned maturin, pytest, numpy from PyPI, made
//! once); the module is built in `<target>/python-ext` so maturin's build environment does not
//! invalidate the workspace's own pyo3 build.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::json;
use stereo_io::*;

use pinned_venv::{ensure_venv, run};
use test_support::io_fixtures::{left_view_meta, patterned_rgb, write_sample_images};
use test_support::{
    pinned_venv,
    python_envs::{MATURIN_PINS, install_stereogen_module},
};

fn rgb(w: usize, h: usize, seed: u8) -> RgbImage {
    patterned_rgb(w, h, 31, seed)
}

fn disp(w: usize, h: usize, seed: f32) -> DisparityMap {
    let mut m = DisparityMap::new(w, h);
    for (i, (d, v)) in m.data.iter_mut().zip(m.valid.iter_mut()).enumerate() {
        *v = i % 6 != 1;
        *d = if *v { seed + i as f32 * 0.75 } else { 0.0 };
    }
    m
}

fn npy(path: PathBuf, h: usize, w: usize, c: usize, data: Vec<f32>) {
    write_npy(
        &path,
        &NpyArray {
            shape: if c == 1 { vec![h, w] } else { vec![h, w, c] },
            data,
        },
    )
    .unwrap();
}

/// Our layout with two samples; sample i's files in the folder `folder(i)` under `root`.
fn write_ours(root: &Path, folder: impl Fn(usize) -> String, w: usize, h: usize) {
    let mut manifest = String::new();
    for (i, id) in ["0000000", "0000001"].iter().enumerate() {
        let rel = folder(i);
        let cat = root.join(&rel);
        std::fs::create_dir_all(&cat).unwrap();
        let meta = left_view_meta(80.0, 0.12);
        write_sample_images(
            &cat,
            id,
            [&rgb(w, h, i as u8), &rgb(w, h, 50 + i as u8)],
            [&disp(w, h, 1.0 + i as f32), &disp(w, h, 2.0)],
            &meta,
        );
        let files = json!({"left": format!("{rel}/{id}_left.png"), "right": format!("{rel}/{id}_right.png"), "disp_left": format!("{rel}/{id}_left.disp.exr"), "disp_right": format!("{rel}/{id}_right.disp.exr"), "scene": format!("{rel}/{id}.scene.json")});
        manifest += &(json!({"id": id, "category": "primitives", "index": i, "files": files, "width": w, "height": h, "f_px": 80.0, "baseline_m": 0.12, "cx": 2.5, "cy": 2.0}).to_string() + "\n");
    }
    std::fs::write(root.join("manifest.jsonl"), manifest).unwrap();
}

/// Writes the fixture datasets and the Rust readers' results; returns the expectations.
fn fixtures(dir: &Path) -> serde_json::Value {
    let (w, h) = (5, 4);
    // Ours: two samples.
    let ours = dir.join("ours");
    write_ours(&ours, |_| "primitives".into(), w, h);
    // A merged farm output: the top-level manifest points into the shards' folders.
    write_ours(
        &dir.join("merged"),
        |i| format!("shards/{i:04}-of-0002/primitives"),
        w,
        h,
    );
    // Middlebury: inf = invalid, calib.txt.
    let mb = dir.join("middlebury/Piano");
    std::fs::create_dir_all(&mb).unwrap();
    write_png_rgb(&mb.join("im0.png"), &rgb(w, h, 7)).unwrap();
    write_png_rgb(&mb.join("im1.png"), &rgb(w, h, 8)).unwrap();
    write_disparity_pfm(&mb.join("disp0.pfm"), &disp(w, h, 30.5)).unwrap();
    std::fs::write(mb.join("calib.txt"), "cam0=[2826.171 0 1292.2; 0 2826.171 965.806; 0 0 1]\ncam1=[2826.171 0 1415.97; 0 2826.171 965.806; 0 0 1]\ndoffs=123.77\nbaseline=178.089\nwidth=5\nheight=4\nndisp=260\n").unwrap();
    // KITTI 2015 with a non-occlusion mask.
    let kt = dir.join("kitti/training");
    for d in ["image_2", "image_3", "disp_occ_0", "disp_noc_0"] {
        std::fs::create_dir_all(kt.join(d)).unwrap();
    }
    write_png_rgb(&kt.join("image_2/000000_10.png"), &rgb(w, h, 9)).unwrap();
    write_png_rgb(&kt.join("image_3/000000_10.png"), &rgb(w, h, 10)).unwrap();
    write_disparity_png16(
        &kt.join("disp_occ_0/000000_10.png"),
        &disp(w, h, 4.0),
        256.0,
    )
    .unwrap();
    let mut noc = disp(w, h, 4.0);
    noc.valid[0] = false;
    write_disparity_png16(&kt.join("disp_noc_0/000000_10.png"), &noc, 256.0).unwrap();

    // What the Rust readers return, for pytest to compare with.
    let refs = dir.join("ref");
    std::fs::create_dir_all(&refs).unwrap();
    let mut datasets = serde_json::Map::new();
    for name in ["ours", "merged", "middlebury", "kitti"] {
        let ds = open_dataset(&dir.join(name), None).unwrap();
        let mut ids = vec![];
        let mut meta = serde_json::Map::new();
        for i in 0..ds.len() {
            let s = ds.sample(i).unwrap();
            ids.push(s.meta.id.clone());
            let f = |v: &[u8]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
            npy(
                refs.join(format!("{name}_{i}_left.npy")),
                h,
                w,
                3,
                f(&s.left.data),
            );
            npy(
                refs.join(format!("{name}_{i}_right.npy")),
                h,
                w,
                3,
                f(&s.right.data),
            );
            npy(
                refs.join(format!("{name}_{i}_disp_left.npy")),
                h,
                w,
                1,
                s.disp_left.data.clone(),
            );
            npy(
                refs.join(format!("{name}_{i}_valid_left.npy")),
                h,
                w,
                1,
                s.valid_mask().iter().map(|&v| v as u8 as f32).collect(),
            );
            for (k, v) in [
                ("f_px", s.meta.f_px),
                ("baseline_m", s.meta.baseline_m),
                ("cx", s.meta.cx),
            ] {
                if let Some(v) = v {
                    meta.insert(k.into(), json!(v));
                }
            }
            if let Some(n) = s.meta.ndisp {
                meta.insert("ndisp".into(), json!(n));
            }
        }
        datasets.insert(
            name.into(),
            json!({"format": ds.format().name(), "len": ds.len(), "ids": ids, "meta": meta}),
        );
    }
    // The merged view reads the same pixels from inside the shards.
    let (a, b) = (
        open_dataset(&ours, None).unwrap(),
        open_dataset(&dir.join("merged"), None).unwrap(),
    );
    for i in 0..a.len() {
        let (x, y) = (a.sample(i).unwrap(), b.sample(i).unwrap());
        assert_eq!(
            (x.left.data, x.disp_left.data),
            (y.left.data, y.disp_left.data)
        );
    }
    let exr = "primitives/0000001_left.disp.exr";
    let (m, em) = read_disparity(&ours.join(exr), None).unwrap();
    npy(refs.join("exr_disp.npy"), h, w, 1, m.data.clone());
    npy(
        refs.join("exr_valid.npy"),
        h,
        w,
        1,
        m.valid.iter().map(|&v| v as u8 as f32).collect(),
    );

    // Broken inputs and the messages Rust gives for them.
    let bad = dir.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("cut.pfm"), b"Pf\n4 4\n-1.0\n\0\0").unwrap();
    std::fs::write(bad.join("noise.exr"), b"\x76\x2f\x31\x01garbage").unwrap();
    let mut errors = vec![];
    for p in [
        bad.join("cut.pfm"),
        bad.join("noise.exr"),
        bad.join("missing.pfm"),
    ] {
        let e = read_disparity(&p, None).unwrap_err();
        let ty = if matches!(e, Error::Io { .. }) {
            "OSError"
        } else {
            "ValueError"
        };
        errors.push(
            json!({"call": "read_disparity", "path": p, "type": ty, "message": e.to_string()}),
        );
    }
    let broken = dir.join("broken_ours");
    std::fs::create_dir_all(broken.join("primitives")).unwrap();
    std::fs::copy(ours.join("manifest.jsonl"), broken.join("manifest.jsonl")).unwrap();
    std::fs::write(
        broken.join("primitives/0000000_left.png"),
        b"\x89PNG\r\n\x1a\nbroken",
    )
    .unwrap();
    let e = open_dataset(&broken, None).unwrap().sample(0).unwrap_err();
    errors.push(json!({"call": "open_dataset", "path": broken, "type": "ValueError", "message": e.to_string()}));

    // The sidecar logs, written by the generator's appender; pytest reads them back.
    use stereo_io::datasets::stereogen::{FailureRecord, SkippedAssetRecord, append_sidecar};
    let failures = vec![
        FailureRecord::new(3, "worker crashed", None),
        FailureRecord::new(
            5,
            "scene raised",
            Some("Traceback (most recent call last)".into()),
        ),
    ];
    append_sidecar(&ours.join("failures.jsonl"), &failures).unwrap();
    let skipped = vec![SkippedAssetRecord::new(
        dir.join("meshes/nan.obj"),
        "a vertex is not finite",
        Some(1),
    )];
    append_sidecar(&ours.join("skipped_assets.jsonl"), &skipped).unwrap();
    let newer = bad.join("failures.jsonl");
    std::fs::write(&newer, "{\"version\":9,\"index\":0,\"error\":\"x\"}\n").unwrap();
    let e = stereo_io::datasets::stereogen::read_failures(&newer).unwrap_err();
    errors.push(json!({"call": "read_failures", "path": newer, "type": "ValueError", "message": e.to_string()}));
    let sidecars = json!({"failures": failures, "skipped_assets": skipped});

    json!({"datasets": datasets, "exr": exr, "exr_f_px": em.f_px, "errors": errors, "sidecars": sidecars})
}

#[test]
fn python_module_matches_the_rust_readers() {
    let venv = ensure_venv("venv-test", MATURIN_PINS);
    install_stereogen_module(&venv);
    let dir = tempfile::tempdir().unwrap();
    let expect = fixtures(dir.path());
    std::fs::write(
        dir.path().join("expect.json"),
        serde_json::to_string_pretty(&expect).unwrap(),
    )
    .unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    run(
        Command::new(venv.join("bin/python"))
            .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
            .arg(root.join("crates/stereogen-py/pytests"))
            .env("STEREOGEN_PY_FIXTURES", dir.path())
            .env("STEREOGEN_BIN", test_support::stereogen_bin()),
        "pytest",
    );
}
