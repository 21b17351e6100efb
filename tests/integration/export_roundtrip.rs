//! `stereogen export` on a real rendered dataset, read back with the matching stereo-io reader:
//! the same pictures and the same disparities within each format's quantisation; and an export
//! of one of those exports (a dataset that is not ours) to another layout.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use test_support::files::walk;

use stereo_io::{DatasetFormat, DisparityMap, open_dataset};
use test_support::{export_cmd, run_ok};

fn generate(dir: &Path) -> PathBuf {
    test_support::generate_tiny_dataset(dir, "ours", 2, 3)
}

/// `stereogen export` of `data` as `format` into `out` with `extra` flags; asserts it succeeded.
fn export_ok(data: &Path, format: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    run_ok(export_cmd(data, format, out).args(extra))
}

/// Same validity everywhere, and values within `tol` on valid pixels.
fn assert_close(got: &DisparityMap, want: &DisparityMap, tol: f32, what: &str) {
    assert_eq!((got.width, got.height), (want.width, want.height), "{what}");
    assert_eq!(got.valid, want.valid, "{what}: validity");
    let mut worst = 0f32;
    for ((g, w), v) in got.data.iter().zip(&want.data).zip(&want.valid) {
        if *v {
            worst = worst.max((g - w).abs());
        }
    }
    assert!(worst <= tol, "{what}: max error {worst} > {tol}");
}

/// `path` is a real JPEG: exactly libjpeg-turbo's encoding of `want` at quality 95, 4:4:4 (the
/// export's default), and `got` (its decode) is that encoding's pixels.
fn assert_jpeg_of(path: &Path, got: &stereo_io::RgbImage, want: &stereo_io::RgbImage) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(
        &bytes[..3],
        &[0xFF, 0xD8, 0xFF],
        "{} is a real JPEG",
        path.display()
    );
    let expected = stereo_io::encode_jpeg_rgb(want, stereo_io::JpegOptions::default()).unwrap();
    assert!(
        bytes == expected,
        "{}: not the quality-95 4:4:4 JPEG of the source pixels",
        path.display()
    );
    let decoded = stereo_io::decode_jpeg(&expected, path).unwrap();
    assert_eq!(
        decoded.samples,
        stereo_io::Samples::U8(got.data.clone()),
        "{}",
        path.display()
    );
}

fn same_inode(a: &Path, b: &Path) -> bool {
    std::fs::metadata(a).unwrap().ino() == std::fs::metadata(b).unwrap().ino()
}

#[test]
fn export_to_crestereo_kitti_and_middlebury_reads_back_within_quantisation() {
    let dir = tempfile::tempdir().unwrap();
    let data = generate(dir.path());
    let ours = open_dataset(&data, None).unwrap();
    assert_eq!((ours.format(), ours.len()), (DatasetFormat::Stereogen, 2));
    let ours: Vec<_> = (0..ours.len()).map(|i| ours.sample(i).unwrap()).collect();
    assert!(
        ours.iter().all(|s| s.disp_left.valid.iter().any(|&v| v)),
        "rendered samples have valid disparity"
    );

    let layouts = [
        ("crestereo", DatasetFormat::Crestereo, 0.5 / 32.0),
        ("kitti2012", DatasetFormat::Kitti2012, 0.5 / 256.0),
        ("kitti", DatasetFormat::Kitti2015, 0.5 / 256.0),
        ("middlebury", DatasetFormat::Middlebury, 0.0),
    ];
    for (format, expect, tol) in layouts {
        let out = dir.path().join(format);
        export_ok(&data, format, &out, &[]);
        let back = open_dataset(&out, None).unwrap();
        assert_eq!(
            back.format(),
            expect,
            "{format} export is recognised as {expect}"
        );
        assert_eq!(back.len(), ours.len());
        for (n, want) in ours.iter().enumerate() {
            let (cat, id) = (&want.meta.extra["category"], &want.meta.id);
            let name = match format {
                "crestereo" => format!("{cat}/{id}"),
                "kitti2012" => format!("training/colored_0/{n:06}_10.png"),
                "kitti" => format!("training/image_2/{n:06}_10.png"),
                _ => format!("Middlebury2014/train/{cat}_{id}-perfect"),
            };
            let i = (0..back.len())
                .find(|&i| back.id(i) == Some(name.as_str()))
                .unwrap_or_else(|| panic!("{format}: no sample {name}"));
            let got = back.sample(i).unwrap();
            assert_close(
                &got.disp_left,
                &want.disp_left,
                tol,
                &format!("{format} {name} left"),
            );
            if format.starts_with("kitti") {
                assert!(
                    got.disp_right.is_none(),
                    "{format}: KITTI holds no right-view disparity"
                );
            } else {
                assert_close(
                    got.disp_right.as_ref().unwrap(),
                    want.disp_right.as_ref().unwrap(),
                    tol,
                    &format!("{format} {name} right"),
                );
            }
            if format == "crestereo" {
                // CREStereo's files are real JPEGs (quality 95, 4:4:4) of our PNGs.
                assert_jpeg_of(&got.meta.left_path, &got.left, &want.left);
                assert_jpeg_of(&got.meta.right_path, &got.right, &want.right);
                continue;
            }
            assert_eq!(got.left, want.left, "{format} {name}: left image");
            assert_eq!(got.right, want.right, "{format} {name}: right image");
            // Images are our PNG files, linked rather than re-encoded.
            assert!(
                same_inode(&got.meta.left_path, &want.meta.left_path),
                "{format}: {} is not a hard link",
                got.meta.left_path.display()
            );
            if format == "middlebury" {
                assert_eq!((got.meta.f_px, got.meta.cx), (want.meta.f_px, want.meta.cx));
                // Our rig's centred principal point, in calib.txt's 0-based pixel centres.
                let width: f64 = want.meta.extra["width"].parse().unwrap();
                assert_eq!(got.meta.cx, Some((width - 1.0) / 2.0));
                assert!(
                    (got.meta.baseline_m.unwrap() - want.meta.baseline_m.unwrap()).abs() < 1e-12
                );
                let max = want.disp_left.stats().unwrap().max;
                assert!(
                    got.meta.ndisp.unwrap() as f32 > max,
                    "ndisp bounds the disparities"
                );
            }
        }
        // Exporting again over a finished export succeeds (every file is replaced atomically).
        export_ok(&data, format, &out, &[]);
    }

    // A dataset that is not ours: the Middlebury export, written as CREStereo's layout.
    let out = dir.path().join("middlebury_to_crestereo");
    let o = export_ok(
        &dir.path().join("middlebury"),
        "crestereo",
        &out,
        &["--from-format", "middlebury"],
    );
    let back = open_dataset(&out, None).unwrap();
    assert_eq!(
        (back.format(), back.len()),
        (DatasetFormat::Crestereo, ours.len())
    );
    for want in &ours {
        let name = format!(
            "Middlebury2014_train_{}_{}-perfect",
            want.meta.extra["category"], want.meta.id
        );
        let i = (0..back.len())
            .find(|&i| back.id(i) == Some(name.as_str()))
            .unwrap_or_else(|| panic!("no sample {name}"));
        let got = back.sample(i).unwrap();
        assert_jpeg_of(&got.meta.left_path, &got.left, &want.left);
        assert_jpeg_of(&got.meta.right_path, &got.right, &want.right);
        assert_close(
            &got.disp_left,
            &want.disp_left,
            0.5 / 32.0,
            &format!("{name} left"),
        );
        assert_close(
            got.disp_right.as_ref().unwrap(),
            want.disp_right.as_ref().unwrap(),
            0.5 / 32.0,
            &format!("{name} right"),
        );
    }
    // Middlebury -> KITTI 2012, the variant named explicitly (our export is "-perfect" only).
    let out = dir.path().join("middlebury_to_kitti2012");
    export_ok(
        &dir.path().join("middlebury"),
        "kitti2012",
        &out,
        &[
            "--from-format",
            "middlebury",
            "--middlebury-variant",
            "perfect",
        ],
    );
    let kitti = open_dataset(&out, None).unwrap();
    assert_eq!(
        (kitti.format(), kitti.len()),
        (DatasetFormat::Kitti2012, ours.len())
    );
    let index = std::fs::read_to_string(out.join("stereogen_samples.tsv")).unwrap();
    for (n, line) in index.lines().enumerate() {
        let source = line.rsplit('\t').next().unwrap();
        let want = ours
            .iter()
            .find(|w| {
                source
                    == format!(
                        "Middlebury2014/train/{}_{}-perfect",
                        w.meta.extra["category"], w.meta.id
                    )
            })
            .unwrap_or_else(|| panic!("{line}"));
        let got = kitti.sample(n).unwrap();
        assert_eq!(
            (&got.left, &got.right),
            (&want.left, &want.right),
            "{line}: PNG images pass through"
        );
        assert_close(&got.disp_left, &want.disp_left, 0.5 / 256.0, line);
    }
    let bad = export_cmd(
        &dir.path().join("middlebury"),
        "kitti2012",
        &dir.path().join("x"),
    )
    .args(["--middlebury-variant", "exact"])
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && err.contains("perfect, imperfect or both"),
        "{err}"
    );

    let o = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.contains("have no CREStereo category")
            && o.contains("tree/, shapenet/, reflective/ and hole/"),
        "the export says which loaders miss uncategorised samples: {o}"
    );
}

#[test]
fn crestereo_export_follows_the_official_loader_paths_and_jpeg_option() {
    let dir = tempfile::tempdir().unwrap();
    let data = generate(dir.path());
    let out = dir.path().join("cre");
    export_ok(
        &data,
        "crestereo",
        &out,
        &["--jpeg-quality", "90", "--jpeg-chroma", "4:2:0"],
    );
    // The official CREStereo loader: glob("**/*_left.jpg"), prefix = path[:rfind("_")],
    // then prefix + "_right.jpg", "_left.disp.png", "_right.disp.png" (cv2 IMREAD_UNCHANGED / 32).
    let lefts: Vec<PathBuf> = walk(&out)
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with("_left.jpg"))
        .collect();
    assert_eq!(lefts.len(), 2);
    for left in lefts {
        let s = left.to_string_lossy();
        let prefix = &s[..s.rfind('_').unwrap()];
        for suffix in ["_right.jpg", "_left.disp.png", "_right.disp.png"] {
            assert!(
                Path::new(&format!("{prefix}{suffix}")).is_file(),
                "{prefix}{suffix}"
            );
        }
        let bytes = std::fs::read(&left).unwrap();
        assert_eq!(&bytes[..3], &[0xFF, 0xD8, 0xFF], "a real JPEG");
        assert_eq!(
            stereo_io::jpeg::chroma_sampling(&bytes),
            Some(stereo_io::ChromaSampling::Half),
            "--jpeg-chroma 4:2:0"
        );
        let disp = stereo_io::read_image(Path::new(&format!("{prefix}_left.disp.png"))).unwrap();
        assert!(
            disp.channels == 1 && matches!(disp.samples, stereo_io::Samples::U16(_)),
            "16-bit grey disparity"
        );
    }
    // Loaders that list the release's four category folders find every folder.
    for category in ["tree", "shapenet", "reflective", "hole"] {
        assert!(
            out.join(category).is_dir(),
            "{category}/ exists even without samples"
        );
    }
    let o = export_cmd(&dir.path().join("nothing"), "kitti", &dir.path().join("k"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("nothing") && err.contains("manifest.jsonl"),
        "{err}"
    );
}
