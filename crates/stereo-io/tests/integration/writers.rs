//! Each layout's writer read back through the same layout's reader, and whole datasets of other
//! layouts exported to CREStereo's.

use std::os::unix::fs::MetadataExt;
use std::path::Path;

use stereo_io::*;

use crate::io_fixtures;
use io_fixtures::*;

/// The largest difference of one channel value between two images of the same size (what a
/// JPEG changed).
fn worst_difference(a: &RgbImage, b: &RgbImage) -> u8 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap()
}

/// A sample with a camera, built from pixels only (no source files to link).
fn sample(seed: u8, with_right: bool) -> StereoSample {
    let meta = SampleMeta {
        f_px: Some(64.0),
        baseline_m: Some(0.1),
        cx: Some(1.5),
        cy: Some(1.0),
        ..Default::default()
    };
    let right = with_right.then(|| disp(f32::from(seed) + 0.5));
    StereoSample {
        left: rgb(seed),
        right: rgb(seed + 40),
        disp_left: disp(f32::from(seed)),
        disp_right: right,
        valid_left: None,
        meta,
    }
}

fn write_all(
    format: WritableFormat,
    root: &Path,
    samples: &[(&str, StereoSample)],
) -> WriteSummary {
    let mut w = create_writer(format, root, ImageEncoding::Lossless).unwrap();
    for (n, (name, s)) in samples.iter().enumerate() {
        w.write(n, name, s).unwrap();
    }
    w.summary().clone()
}

#[test]
fn each_writer_round_trips_through_its_reader() {
    let samples = [
        ("tree/0000000", sample(2, true)),
        ("tree/0000001", sample(9, false)),
    ];
    for format in WritableFormat::ALL {
        let t = tempfile::tempdir().unwrap();
        let s = write_all(format, t.path(), &samples);
        // KITTI holds no right-view disparity (its disp_occ_1 is a later frame's).
        let kitti = matches!(
            format,
            WritableFormat::Kitti2012 | WritableFormat::Kitti2015
        );
        let without_right = if kitti { 2 } else { 1 };
        assert_eq!(
            (
                s.samples,
                s.without_right_disparity,
                s.dropped_pixels,
                s.linked
            ),
            (2, without_right, 0, 0),
            "{format}"
        );
        let ds = open_dataset(t.path(), None).unwrap();
        assert_eq!((ds.format(), ds.len()), (format.dataset_format(), 2));
        let ids = match format {
            WritableFormat::Crestereo => ["tree/0000000", "tree/0000001"],
            WritableFormat::Kitti2012 => [
                "training/colored_0/000000_10.png",
                "training/colored_0/000001_10.png",
            ],
            WritableFormat::Kitti2015 => [
                "training/image_2/000000_10.png",
                "training/image_2/000001_10.png",
            ],
            WritableFormat::Middlebury => [
                "Middlebury2014/train/tree_0000000-perfect",
                "Middlebury2014/train/tree_0000001-perfect",
            ],
        };
        for (i, (_, want)) in samples.iter().enumerate() {
            assert_eq!(ds.id(i), Some(ids[i]), "{format}");
            let got = ds.sample(i).unwrap();
            if format == WritableFormat::Crestereo {
                // Real JPEG (quality 95, 4:4:4) of a 4x3 ramp with steps of 7 levels: within 16.
                for (g, w) in [(&got.left, &want.left), (&got.right, &want.right)] {
                    let worst = worst_difference(g, w);
                    assert!(
                        worst <= 16,
                        "{format} {i}: JPEG far from the pixels ({worst})"
                    );
                }
            } else {
                assert_eq!(
                    (&got.left, &got.right),
                    (&want.left, &want.right),
                    "{format} {i}: images"
                );
            }
            // Every value of `disp` is a multiple of 1/4: exact at x32, x256 and in PFM.
            assert_disp_eq(&got.disp_left, &want.disp_left);
            match (&got.disp_right, &want.disp_right) {
                (Some(g), Some(w)) => assert_disp_eq(g, w),
                (None, None) => {}
                (None, Some(_)) if kitti => {}
                other => panic!("{format} {i}: right disparity {other:?}"),
            }
            if format == WritableFormat::Middlebury {
                assert_eq!(
                    (got.meta.f_px, got.meta.cx, got.meta.cy),
                    (Some(64.0), Some(1.5), Some(1.0))
                );
                assert!((got.meta.baseline_m.unwrap() - 0.1).abs() < 1e-12);
                assert!(got.meta.ndisp.unwrap() as f32 > want.disp_left.stats().unwrap().max);
            }
        }
        // Writing again where a sample now lacks its right disparity leaves no stale file.
        let swapped = [
            ("tree/0000000", sample(2, false)),
            ("tree/0000001", sample(9, false)),
        ];
        write_all(format, t.path(), &swapped);
        let ds = open_dataset(t.path(), None).unwrap();
        assert!(
            ds.sample(0).unwrap().disp_right.is_none(),
            "{format}: a stale right disparity is still read"
        );
    }
}

#[test]
fn kitti_writes_disp_noc_where_the_source_has_a_stricter_mask() {
    let t = tempfile::tempdir().unwrap();
    let mut s = sample(2, false);
    let mut keep = s.disp_left.valid.clone();
    keep[0] = false;
    s.valid_left = Some(keep.clone());
    for (format, noc) in [
        (WritableFormat::Kitti2012, "disp_noc"),
        (WritableFormat::Kitti2015, "disp_noc_0"),
    ] {
        let root = t.path().join(format.to_string());
        write_all(format, &root, &[("x", s.clone()), ("y", sample(3, false))]);
        assert!(
            root.join("training")
                .join(noc)
                .join("000000_10.png")
                .is_file(),
            "{format}"
        );
        assert!(
            !root
                .join("training")
                .join(noc)
                .join("000001_10.png")
                .exists(),
            "{format}: no mask, no {noc}"
        );
        let ds = open_dataset(&root, None).unwrap();
        let got = ds.sample(0).unwrap();
        assert_disp_eq(&got.disp_left, &s.disp_left);
        assert_eq!(got.valid_left.as_ref(), Some(&keep), "{format}");
        assert!(ds.sample(1).unwrap().valid_left.is_none());
    }
}

#[test]
fn kitti_computes_disp_noc_from_both_views_and_repeats_still_frames() {
    let t = tempfile::tempdir().unwrap();
    // Ours (a still scene, both views' ground truth), a SceneFlow pair (things move between
    // frames) and one with no right-view map. Disparity 1 everywhere, except that the right
    // view sees a nearer surface (3) at its pixel 1, hiding what the left view's pixel 2 sees.
    let ours = |seed| {
        let mut s = sample(seed, true);
        s.meta.format = Some(DatasetFormat::Stereogen);
        let left = &mut s.disp_left;
        left.data = left.valid.iter().map(|&v| f32::from(u8::from(v))).collect();
        let right = s.disp_right.as_mut().unwrap();
        right.valid.fill(true);
        right.data.fill(1.0);
        right.data[1] = 3.0;
        s
    };
    let mut moving = ours(3);
    moving.meta.format = Some(DatasetFormat::SceneFlow);
    let mut no_right = sample(4, false);
    no_right.meta.format = Some(DatasetFormat::Stereogen);
    let samples = [("a", ours(2)), ("b", moving), ("c", no_right)];
    let seen = |s: &StereoSample| {
        s.disp_left
            .left_right_consistent(s.disp_right.as_ref().unwrap(), LEFT_RIGHT_TOLERANCE_PX)
    };
    for (format, noc, next) in [
        (WritableFormat::Kitti2012, "disp_noc", &[][..]),
        (
            WritableFormat::Kitti2015,
            "disp_noc_0",
            &[("disp_occ_0", "disp_occ_1"), ("disp_noc_0", "disp_noc_1")][..],
        ),
    ] {
        let root = t.path().join(format.to_string());
        write_all(format, &root, &samples);
        let training = root.join("training");
        let ds = open_dataset(&root, None).unwrap();
        for (n, (_, s)) in samples.iter().enumerate() {
            let got = ds.sample(n).unwrap();
            let frame = format!("{n:06}_10.png");
            match &s.disp_right {
                Some(_) => {
                    let keep = seen(s);
                    assert!(
                        keep.contains(&false) && keep.contains(&true),
                        "a mixed mask"
                    );
                    assert_eq!(got.valid_left.as_ref(), Some(&keep), "{format} {frame}");
                }
                None => assert!(!training.join(noc).join(&frame).exists(), "{format}"),
            }
            // The next frame of a still scene is this frame: the same files, byte for byte.
            let still = s.meta.format == Some(DatasetFormat::Stereogen);
            for (this, next) in next {
                let (this, next) = (
                    training.join(this).join(&frame),
                    training.join(next).join(&frame),
                );
                if still && this.exists() {
                    let same = std::fs::read(&next).unwrap() == std::fs::read(&this).unwrap();
                    assert!(
                        same,
                        "{format}: {} differs from {}",
                        next.display(),
                        this.display()
                    );
                } else {
                    assert!(
                        !next.exists(),
                        "{format}: {} of a pair that is not still",
                        next.display()
                    );
                }
            }
        }
    }
}

#[test]
fn crestereo_export_names_what_torchvisions_loader_would_refuse() {
    let t = tempfile::tempdir().unwrap();
    let every_category: Vec<(String, StereoSample)> = ["tree", "shapenet", "reflective", "hole"]
        .iter()
        .map(|c| (format!("{c}/0000000"), sample(2, true)))
        .collect();
    let named: Vec<(&str, StereoSample)> = every_category
        .iter()
        .map(|(n, s)| (n.as_str(), s.clone()))
        .collect();
    let whole = write_all(WritableFormat::Crestereo, &t.path().join("a"), &named);
    assert_eq!(
        whole.loader_notes(WritableFormat::Crestereo, t.path()),
        Vec::<String>::new()
    );

    let partial = write_all(
        WritableFormat::Crestereo,
        &t.path().join("b"),
        &[
            ("tree/0000000", sample(2, true)),
            ("hole/0000001", sample(3, false)),
        ],
    );
    let notes = partial.loader_notes(WritableFormat::Crestereo, t.path());
    assert_eq!(notes.len(), 2, "{notes:#?}");
    assert!(
        notes[0].starts_with("no sample in shapenet/, reflective/ of "),
        "{}",
        notes[0]
    );
    assert!(
        notes[0].contains("torchvision's CREStereo loader"),
        "{}",
        notes[0]
    );
    assert!(
        notes[1].starts_with("1 sample(s) have no right-view disparity"),
        "{}",
        notes[1]
    );
    // Other layouts have no such loader rule.
    assert!(
        partial
            .loader_notes(WritableFormat::Kitti2015, t.path())
            .is_empty()
    );
}

#[test]
fn sixteen_bit_layouts_drop_what_they_cannot_hold_and_count_it() {
    for (format, max) in [
        (WritableFormat::Kitti2015, 256.0),
        (WritableFormat::Crestereo, 2048.0),
    ] {
        let t = tempfile::tempdir().unwrap();
        let mut s = sample(1, true);
        s.disp_left.data[0] = max;
        s.disp_left.data[1] = max - 0.25;
        s.disp_left.data[2] = -1.0;
        let summary = write_all(format, t.path(), &[("x", s)]);
        assert_eq!(summary.dropped_pixels, 2, "{format}");
        let got = open_dataset(t.path(), None).unwrap().sample(0).unwrap();
        assert_eq!(&got.disp_left.valid[..3], &[false, true, false], "{format}");
        assert_eq!(got.disp_left.data[1], max - 0.25);
    }
}

#[test]
fn middlebury_calib_needs_the_camera_and_states_doffs() {
    let t = tempfile::tempdir().unwrap();
    let mut w = create_writer(
        WritableFormat::Middlebury,
        t.path(),
        ImageEncoding::Lossless,
    )
    .unwrap();
    let mut s = sample(1, true);
    s.meta.baseline_m = None;
    s.meta.cx = None;
    let e = w.write(0, "a", &s).unwrap_err().to_string();
    assert!(
        e.contains("calib.txt") && e.contains("no baseline_m, cx"),
        "{e}"
    );
    assert!(
        !t.path().join("Middlebury2014/train/a-perfect").exists(),
        "nothing is written for a sample that cannot be"
    );
    // A Middlebury source keeps its doffs: cam1's cx is cam0's plus doffs.
    let mut s = sample(1, true);
    s.meta.extra.insert("doffs".into(), "131.5".into());
    w.write(1, "b", &s).unwrap();
    let calib =
        std::fs::read_to_string(t.path().join("Middlebury2014/train/b-perfect/calib.txt")).unwrap();
    // cx = 1.5 and cy = 1 (pixel centres) are 2 and 1.5 in calib.txt's corner-origin convention.
    assert!(calib.contains("cam0=[64 0 2; 0 64 1.5; 0 0 1]\ncam1=[64 0 133.5; 0 64 1.5; 0 0 1]\ndoffs=131.5\nbaseline=100\n"), "{calib}");
}

#[test]
fn crestereo_jpegs_are_real_jpegs_at_the_asked_quality() {
    let t = tempfile::tempdir().unwrap();
    let mut w =
        create_writer(WritableFormat::Crestereo, t.path(), ImageEncoding::Jpeg(95)).unwrap();
    w.write(0, "pair000", &sample(3, true)).unwrap();
    let bytes = std::fs::read(t.path().join("pair000_left.jpg")).unwrap();
    assert_eq!(&bytes[..3], &[0xFF, 0xD8, 0xFF]);
    let back = open_dataset(t.path(), None).unwrap().sample(0).unwrap();
    let worst = worst_difference(&back.left, &rgb(3));
    assert!(
        worst < 40,
        "JPEG at quality 95 is close to the pixels (worst {worst})"
    );
}

fn same_inode(a: &Path, b: &Path) -> bool {
    std::fs::metadata(a).unwrap().ino() == std::fs::metadata(b).unwrap().ino()
}

#[test]
fn sceneflow_and_middlebury_export_to_crestereo_and_read_back() {
    let t = tempfile::tempdir().unwrap();
    let sf = t.path().join("sf");
    sceneflow(&sf.join("FlyingThings3D"));
    let mb = t.path().join("mb");
    let mb_disp = middlebury_scene(&mb.join("trainingF/Adirondack"));
    let opts = |from| ExportOptions {
        from,
        to: WritableFormat::Crestereo,
        images: ImageEncoding::Lossless,
        read: ReadOptions::default(),
    };

    let out = t.path().join("sf_cre");
    let s = export_dataset(&sf, &out, &opts(None)).unwrap();
    assert_eq!(
        (
            s.samples,
            s.without_right_disparity,
            s.linked,
            s.outside_categories
        ),
        (1, 0, 0, 1)
    );
    let ds = open_dataset(&out, None).unwrap();
    assert_eq!((ds.format(), ds.len()), (DatasetFormat::Crestereo, 1));
    assert_eq!(
        ds.id(0),
        Some("FlyingThings3D_frames_cleanpass_TRAIN_A_0000_left_0006")
    );
    let got = ds.sample(0).unwrap();
    assert_eq!(
        got.meta.id, "FlyingThings3D_frames_cleanpass_TRAIN_A_0000_left_0006",
        "meta.id is the sample's id in every layout"
    );
    for (g, w) in [(&got.left, rgb(1)), (&got.right, rgb(4))] {
        let worst = worst_difference(g, &w);
        assert!(worst <= 16, "JPEG far from the pixels ({worst})");
    }
    assert_disp_eq(&got.disp_left, &disp(1.0));
    assert_disp_eq(got.disp_right.as_ref().unwrap(), &disp(4.0));
    // PNG sources are encoded as real JPEGs: no `.jpg` holds PNG bytes.
    assert!(!same_inode(
        &got.meta.left_path,
        &sf.join("FlyingThings3D/frames_cleanpass/TRAIN/A/0000/left/0006.png")
    ));
    assert_eq!(
        &std::fs::read(&got.meta.left_path).unwrap()[..3],
        &[0xFF, 0xD8, 0xFF]
    );
    // The release's four category folders exist, empty where no sample has that category.
    for category in ["tree", "shapenet", "reflective", "hole"] {
        assert!(out.join(category).is_dir(), "{category}");
    }
    let index = std::fs::read_to_string(out.join("stereogen_samples.tsv")).unwrap();
    assert_eq!(
        index,
        "000000\t\tFlyingThings3D/frames_cleanpass/TRAIN/A/0000/left/0006.png\n"
    );

    // Middlebury has no right-view disparity: the sample is written without one.
    let out = t.path().join("mb_cre");
    let s = export_dataset(&mb, &out, &opts(Some(DatasetFormat::Middlebury))).unwrap();
    assert_eq!((s.samples, s.without_right_disparity), (1, 1));
    let got = open_dataset(&out, Some(DatasetFormat::Crestereo))
        .unwrap()
        .sample(0)
        .unwrap();
    assert_eq!((got.left.width, got.right.height), (W, H));
    assert_disp_eq(&got.disp_left, &mb_disp);
    assert!(got.disp_right.is_none());
    assert!(!out.join("trainingF_Adirondack_right.disp.png").exists());

    // The source as its own output, or a source that is not there, are refused with their names.
    let e = export_dataset(&mb, &mb, &opts(None))
        .unwrap_err()
        .to_string();
    assert!(e.contains("must differ"), "{e}");
    let e = export_dataset(&t.path().join("nothing"), &out, &opts(None))
        .unwrap_err()
        .to_string();
    assert!(e.contains("nothing") && e.contains("manifest.jsonl"), "{e}");
}

#[test]
fn our_principal_point_is_written_to_calib_txt_in_middleburys_corner_origin_convention() {
    let t = tempfile::tempdir().unwrap();
    let root = t.path().join("ours");
    let layout = DatasetLayout::new(&root);
    let paths = layout.sample_paths("tree", "0000000");
    mkdir(&root.join("tree"));
    write_png_rgb(&layout.abs(&paths.left), &rgb(1)).unwrap();
    write_png_rgb(&layout.abs(&paths.right), &rgb(2)).unwrap();
    write_disparity_exr(
        &layout.abs(&paths.disp_left),
        &disp(3.0),
        &DisparityMeta::default(),
    )
    .unwrap();
    write_disparity_exr(
        &layout.abs(&paths.disp_right),
        &disp(3.5),
        &DisparityMeta::default(),
    )
    .unwrap();
    let entry: ManifestEntry = serde_json::from_value(serde_json::json!({
        "id": "0000000", "category": "tree", "index": 0, "files": paths,
        "width": W, "height": H, "f_px": 64.0, "baseline_m": 0.1, "cx": W as f64 / 2.0, "cy": H as f64 / 2.0,
    }))
    .unwrap();
    let (mut manifest, _) = Manifest::open(&layout.manifest()).unwrap();
    manifest.append(&entry).unwrap();

    let out = t.path().join("mb");
    let s = export_dataset(
        &root,
        &out,
        &ExportOptions {
            from: None,
            to: WritableFormat::Middlebury,
            images: ImageEncoding::Lossless,
            read: ReadOptions::default(),
        },
    )
    .unwrap();
    assert_eq!((s.samples, s.linked), (1, 2));
    // Our continuous cx = W/2 = 2 is Middlebury's (cvkit's corner origin) cx = 2 too; read back,
    // it is the pixel centre (W - 1)/2 = 1.5 (and cy = 1.5 is 1).
    let calib =
        std::fs::read_to_string(out.join("Middlebury2014/train/tree_0000000-perfect/calib.txt"))
            .unwrap();
    assert!(
        calib.starts_with(
            "cam0=[64 0 2; 0 64 1.5; 0 0 1]\ncam1=[64 0 2; 0 64 1.5; 0 0 1]\ndoffs=0\n"
        ),
        "{calib}"
    );
    let back = open_dataset(&out, None).unwrap().sample(0).unwrap();
    let ours = open_dataset(&root, None).unwrap().sample(0).unwrap();
    assert_eq!((back.meta.cx, back.meta.cy), (ours.meta.cx, ours.meta.cy));
    assert_eq!(back.meta.cx, Some(1.5));
}
