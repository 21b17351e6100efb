//! Our KITTI 2012, KITTI 2015 and CREStereo exports opened by torchvision's own stereo datasets
//! (`Kitti2012Stereo`, `Kitti2015Stereo`, `CREStereo`, PyPI torchvision in a cached venv):
//! each must accept the export (the KITTI loaders want `disp_noc` and `disp_occ_1`, CREStereo a
//! sample with both disparities in each category folder) and return, for every sample, the
//! pixels and disparities our reader of the same files returns, exactly.
//!
//! torchvision 0.29.2 is installed without its dependencies on top of the trainer's parity venv
//! (torch 2.15.0; torchvision asks for 2.14): the dataset classes are Python and Pillow.

use std::path::Path;

use stereo_io::*;

use crate::pinned_venv;
use crate::python_script_json;
use pinned_venv::{ensure_venv, ensure_venv_on};

/// The trainer's PyTorch parity venv (`crates/crestereo-train/tests/integration/export_pytorch.rs`): reused.
const TORCH_PINS: &[&str] = &["torch==2.15.0", "numpy==2.4.6"];
const TORCHVISION_PINS: &[&str] = &["torchvision==0.29.2", "pillow==13.0.0"];
const W: usize = 48;
const H: usize = 24;
/// Left x of the near box (disparity [`BOX_D`]) in front of the sloped wall.
const BOX: std::ops::Range<usize> = 26..34;
const BOX_D: f32 = 9.0;

fn wall(y: usize) -> f32 {
    3.0 + 0.25 * y as f32
}

/// A still scene seen by both cameras: the near box hides part of the wall from the right
/// view, so the left–right check leaves out a band of wall pixels (and the left border, whose
/// matches fall outside the right image). Quarter-pixel values: exact in every layout.
fn sample(seed: u8) -> StereoSample {
    let mut left = DisparityMap::new(W, H);
    let mut right = DisparityMap::new(W, H);
    for y in 0..H {
        for x in 0..W {
            let i = y * W + x;
            left.data[i] = if BOX.contains(&x) { BOX_D } else { wall(y) };
            left.valid[i] = true;
            let seen_box = (BOX.start - BOX_D as usize..BOX.end - BOX_D as usize).contains(&x);
            right.data[i] = if seen_box { BOX_D } else { wall(y) };
            right.valid[i] = true;
        }
    }
    let image = |k: u8| RgbImage {
        width: W,
        height: H,
        data: (0..W * H * 3)
            .map(|i| ((i * 37 + usize::from(k) * 101) % 251) as u8)
            .collect(),
    };
    StereoSample {
        left: image(seed),
        right: image(seed + 1),
        disp_left: left,
        disp_right: Some(right),
        valid_left: None,
        meta: SampleMeta {
            format: Some(DatasetFormat::Stereogen),
            ..Default::default()
        },
    }
}

fn npy(path: &Path) -> Vec<f32> {
    read_npy(path).unwrap_or_else(|e| panic!("{e}")).data
}

/// What torchvision should return as disparity: ours where valid, 0 elsewhere.
fn zero_filled(d: &DisparityMap, keep: &[bool]) -> Vec<f32> {
    d.data
        .iter()
        .zip(keep)
        .map(|(&v, &k)| if k { v } else { 0.0 })
        .collect()
}

#[test]
fn torchvision_stereo_datasets_open_our_exports_and_read_what_we_read() {
    let torch = ensure_venv("venv-torch", TORCH_PINS);
    let venv = ensure_venv_on(&torch, "venv-torchvision-on-torch", TORCHVISION_PINS);
    let t = tempfile::tempdir().unwrap();
    let exports = t.path().join("exports");
    let names = ["tree", "shapenet", "reflective", "hole"].map(|c| format!("{c}/000000{c}"));
    let samples: Vec<StereoSample> = (0..4u8).map(|k| sample(10 * k)).collect();
    let layouts = [
        ("Kitti2012", WritableFormat::Kitti2012),
        ("Kitti2015", WritableFormat::Kitti2015),
        ("CREStereo", WritableFormat::Crestereo),
    ];
    for (folder, format) in layouts {
        let mut w = create_writer(format, &exports.join(folder), ImageEncoding::Lossless).unwrap();
        for (n, s) in samples.iter().enumerate() {
            w.write(n, &names[n], s).unwrap();
        }
        let notes = w.summary().loader_notes(format, &exports.join(folder));
        assert!(notes.is_empty(), "{format}: {notes:?}");
    }
    let out = t.path().join("read");
    let found = python_script_json(&venv, "torchvision_loaders.py", &exports, &out);

    for (folder, format) in layouts {
        let listed = found[folder].as_array().unwrap();
        assert_eq!(listed.len(), samples.len(), "{folder}: {found}");
        let ours = open_dataset(&exports.join(folder), None).unwrap();
        for (i, left_path) in listed.iter().enumerate() {
            let left_path = left_path.as_str().unwrap();
            let id = match format {
                WritableFormat::Crestereo => left_path.trim_end_matches("_left.jpg").to_string(),
                _ => left_path.to_string(),
            };
            let k = (0..ours.len())
                .find(|&k| ours.id(k) == Some(id.as_str()))
                .unwrap_or_else(|| panic!("{folder}: torchvision found {left_path}; we do not"));
            let s = ours.sample(k).unwrap();
            let file = |what: &str| out.join(folder).join(format!("{i}_{what}.npy"));
            let pixels =
                |img: &RgbImage| img.data.iter().map(|&v| f32::from(v)).collect::<Vec<_>>();
            assert_eq!(
                npy(&file("left")),
                pixels(&s.left),
                "{folder} {left_path}: left"
            );
            assert_eq!(
                npy(&file("right")),
                pixels(&s.right),
                "{folder} {left_path}: right"
            );
            // Kitti2012Stereo reads disp_noc; the others the disparity of every pixel.
            let keep = match format {
                WritableFormat::Kitti2012 => s.valid_left.clone().expect("disp_noc written"),
                _ => s.disp_left.valid.clone(),
            };
            let occluded = keep.iter().filter(|k| !**k).count();
            assert!(
                occluded > 0 || format != WritableFormat::Kitti2012,
                "{folder}: a real mask"
            );
            assert_eq!(
                npy(&file("disp")),
                zero_filled(&s.disp_left, &keep),
                "{folder} {left_path}: disparity"
            );
        }
    }
}
