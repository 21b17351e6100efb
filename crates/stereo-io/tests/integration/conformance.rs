//! Our exports read by loaders nobody on this project wrote: `tests/python/independent_readers.py`
//! finds the samples the way each layout's popular loaders do and decodes them with OpenCV and
//! Pillow (pinned, from PyPI, in a cached venv under `$STEREOGEN_HOME/python`). Images must come
//! back as written (PNG exactly; our JPEGs as our libjpeg-turbo decoder reads them), disparity
//! within half a quantisation step of the source with the same validity, by each format's own
//! rule. The same script writes real-looking JPEGs with OpenCV, which our decoder must read
//! bit-identically.

use std::path::Path;

use stereo_io::*;

use crate::pinned_venv;
use crate::python_script_json;
use pinned_venv::ensure_venv;

const PINS: &[&str] = &[
    "opencv-python-headless==5.0.0.93",
    "pillow==13.0.0",
    "numpy==2.4.6",
];
const W: usize = 72;
const H: usize = 53;

/// Shaded surfaces, a texture, sharp edges and noise: what JPEG quantisation has to work on.
fn photo(seed: u32) -> RgbImage {
    let mut s = seed.wrapping_mul(2_654_435_761);
    let mut noise = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s % 21) as f32 - 10.0
    };
    let mut data = Vec::with_capacity(W * H * 3);
    for y in 0..H {
        for x in 0..W {
            for c in 0..3 {
                let (xf, yf) = (x as f32, y as f32);
                let mut v = 50.0
                    + 140.0 * xf / W as f32 * (c as f32 + 1.0) / 3.0
                    + 35.0 * (yf / (4.0 + c as f32)).sin() * (xf / 6.0).cos();
                if (20..40).contains(&x) && (10..25).contains(&y) {
                    v = 30.0 + 90.0 * c as f32 + seed as f32;
                }
                data.push((v + noise()).clamp(0.0, 255.0) as u8);
            }
        }
    }
    RgbImage {
        width: W,
        height: H,
        data,
    }
}

/// A slanted plane of fractional disparities with a hole of no ground truth.
fn disparity(offset: f32) -> DisparityMap {
    let mut map = DisparityMap::new(W, H);
    for y in 0..H {
        for x in 0..W {
            let i = y * W + x;
            map.data[i] = offset + 1.37 * x as f32 + 0.61 * y as f32 + 0.013 * (x * y) as f32;
            map.valid[i] = !((5..15).contains(&x) && (30..40).contains(&y));
        }
    }
    map
}

fn sample(n: u32) -> StereoSample {
    let meta = SampleMeta {
        f_px: Some(480.0),
        baseline_m: Some(0.12),
        cx: Some((W as f64 - 1.0) / 2.0),
        cy: Some((H as f64 - 1.0) / 2.0),
        ..Default::default()
    };
    StereoSample {
        left: photo(n),
        right: photo(n + 7),
        disp_left: disparity(0.25 + 3.0 * n as f32),
        disp_right: Some(disparity(0.5)),
        valid_left: None,
        meta,
    }
}

/// The samples exported, named as ours are.
fn samples() -> Vec<(&'static str, StereoSample)> {
    vec![("tree/0000000", sample(0)), ("hole/0000001", sample(1))]
}

fn npy(path: &Path) -> NpyArray {
    read_npy(path).unwrap_or_else(|e| panic!("{e}"))
}

/// Largest disparity difference where both are valid, and the fraction of pixels whose validity
/// agrees.
fn compare_disparity(got: &NpyArray, want: &DisparityMap) -> (f32, f64) {
    assert_eq!(got.shape, vec![want.height, want.width]);
    let (mut worst, mut agree) = (0f32, 0usize);
    for (g, (w, v)) in got.data.iter().zip(want.data.iter().zip(&want.valid)) {
        agree += usize::from(g.is_finite() == *v);
        if g.is_finite() && *v {
            worst = worst.max((g - w).abs());
        }
    }
    (worst, agree as f64 / got.data.len() as f64)
}

fn image_as_f32(img: &RgbImage) -> Vec<f32> {
    img.data.iter().map(|&v| f32::from(v)).collect()
}

#[test]
fn every_export_target_reads_back_through_opencv_and_pillow() {
    let venv = ensure_venv("venv-conformance", PINS);
    let t = tempfile::tempdir().unwrap();
    let exports = t.path().join("exports");
    let want = samples();
    let targets = [
        (WritableFormat::Crestereo, 32.0f32),
        (WritableFormat::Kitti2012, 256.0),
        (WritableFormat::Kitti2015, 256.0),
        (WritableFormat::Middlebury, 0.0),
    ];
    for (format, _) in targets {
        let mut w = create_writer(
            format,
            &exports.join(format.to_string()),
            ImageEncoding::Lossless,
        )
        .unwrap();
        for (n, (name, s)) in want.iter().enumerate() {
            w.write(n, name, s).unwrap();
        }
    }
    let out = t.path().join("read");
    let facts = python_script_json(&venv, "independent_readers.py", &exports, &out);
    // The category-listing loaders see every sample of ours.
    assert_eq!(facts["crestereo_listed_by_category"], 2, "{facts}");

    for (format, scale) in targets {
        assert_eq!(
            facts[format.to_string()],
            2,
            "{format}: samples found by the independent loader ({facts})"
        );
        let exported = open_dataset(&exports.join(format.to_string()), None).unwrap();
        let dir = out.join(format.to_string());
        let found = std::fs::read_to_string(dir.join("names.txt")).unwrap();
        for (n, found_name) in found.lines().enumerate() {
            // Which sample the loader found, and our reader's index of the same files.
            let (source, id) = match format {
                WritableFormat::Crestereo => (
                    want.iter().position(|(name, _)| *name == found_name),
                    found_name.to_string(),
                ),
                WritableFormat::Middlebury => (
                    want.iter().position(|(name, _)| {
                        format!("{}-perfect", name.replace('/', "_")) == found_name
                    }),
                    format!("Middlebury2014/train/{found_name}"),
                ),
                _ => (
                    found_name[..6].parse::<usize>().ok(),
                    format!(
                        "training/{}/{found_name}",
                        if format == WritableFormat::Kitti2012 {
                            "colored_0"
                        } else {
                            "image_2"
                        }
                    ),
                ),
            };
            let s = &want[source.unwrap_or_else(|| {
                panic!("{format}: the loader found {found_name}, which was not exported")
            })]
            .1;
            let ours = (0..exported.len())
                .find(|&i| exported.id(i) == Some(id.as_str()))
                .unwrap_or_else(|| panic!("{format}: we do not read {id}"));
            let (left, right) = (
                npy(&dir.join(format!("{n}_left.npy"))),
                npy(&dir.join(format!("{n}_right.npy"))),
            );
            // What the files hold, read by our readers: PNGs are the pixels exactly; JPEGs
            // must decode identically in libjpeg-turbo (OpenCV) and here.
            let ours = exported.sample(ours).unwrap();
            assert_eq!(
                left.data,
                image_as_f32(&ours.left),
                "{format} {n}: left image differs from OpenCV/Pillow's decode"
            );
            assert_eq!(
                right.data,
                image_as_f32(&ours.right),
                "{format} {n}: right image"
            );
            if format != WritableFormat::Crestereo {
                assert_eq!(ours.left, s.left, "{format} {n}: PNG is lossless");
            }
            let (worst, agree) =
                compare_disparity(&npy(&dir.join(format!("{n}_disp.npy"))), &s.disp_left);
            let bound = if scale > 0.0 { 0.5 / scale } else { 0.0 };
            println!(
                "{format} sample {n}: max |d| error {worst:.6} px (bound {bound}), valid-mask agreement {:.4}%",
                100.0 * agree
            );
            assert!(
                worst <= bound + 1e-6,
                "{format} {n}: disparity error {worst} above half a step {bound}"
            );
            assert_eq!(agree, 1.0, "{format} {n}: validity differs");
        }
    }
    for calib in facts["middlebury_calib"].as_array().unwrap() {
        assert_eq!(
            (calib["f"].as_f64(), calib["baseline_mm"].as_f64()),
            (Some(480.0), Some(120.0))
        );
        // Middlebury's corner origin (cvkit): the centred principal point is W/2, H/2.
        assert_eq!(
            (calib["cx"].as_f64(), calib["cy"].as_f64()),
            (Some(W as f64 / 2.0), Some(H as f64 / 2.0))
        );
        assert_eq!(
            (calib["width"].as_u64(), calib["height"].as_u64()),
            (Some(W as u64), Some(H as u64))
        );
    }

    // JPEGs written by OpenCV (4:2:0 and 4:4:4): our decoder gives OpenCV's pixels exactly.
    let jpeg = out.join("jpeg");
    let names = facts["jpegs"].as_array().unwrap();
    assert_eq!(names.len(), 10);
    for name in names {
        let name = name.as_str().unwrap();
        let reference = npy(&jpeg.join(format!("{name}.npy")));
        let ours = read_rgb(&jpeg.join(format!("{name}.jpg"))).unwrap();
        assert_eq!(reference.shape, vec![ours.height, ours.width, 3], "{name}");
        let worst = reference
            .data
            .iter()
            .zip(&ours.data)
            .map(|(a, b)| (a - f32::from(*b)).abs())
            .fold(0f32, f32::max);
        println!("{name}: largest difference to OpenCV {worst}");
        assert_eq!(
            worst, 0.0,
            "{name}: our JPEG decode differs from libjpeg-turbo's"
        );
    }
}
