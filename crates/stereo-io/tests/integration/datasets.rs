//! Each dataset layout built as a tiny fixture with known values, recognised from its folder,
//! read back through the one `StereoDataset` trait.

use std::fs;
use std::path::{Path, PathBuf};

use stereo_io::*;

use crate::io_fixtures;
use io_fixtures::*;

fn grey8(path: &Path, f: impl Fn(usize) -> u8) {
    write_png(
        path,
        &Image {
            width: W,
            height: H,
            channels: 1,
            samples: Samples::U8((0..W * H).map(f).collect()),
        },
    )
    .unwrap();
}

fn jpeg_pair(dir: &Path, left: &str, right: &str) -> (RgbImage, RgbImage) {
    write_jpeg_rgb(&dir.join(left), &rgb(10), 100).unwrap();
    write_jpeg_rgb(&dir.join(right), &rgb(90), 100).unwrap();
    (
        read_rgb(&dir.join(left)).unwrap(),
        read_rgb(&dir.join(right)).unwrap(),
    )
}

fn open(root: &Path, expect: DatasetFormat) -> Box<dyn StereoDataset> {
    assert_eq!(
        detect_format(root).unwrap(),
        expect,
        "detected layout of {}",
        root.display()
    );
    let forced = open_dataset(root, Some(expect)).unwrap();
    let auto = open_dataset(root, None).unwrap();
    assert_eq!(auto.format(), expect);
    assert_eq!(auto.len(), forced.len());
    auto
}

#[test]
fn crestereo_release_layout() {
    let t = tempfile::tempdir().unwrap();
    let dir = mkdir(&t.path().join("stereo_trainset/crestereo/tree"));
    let (l, r) = jpeg_pair(&dir, "a1_left.jpg", "a1_right.jpg");
    write_disparity_png16(&dir.join("a1_left.disp.png"), &disp(2.0), 32.0).unwrap();
    write_disparity_png16(&dir.join("a1_right.disp.png"), &disp(3.0), 32.0).unwrap();
    let ds = open(t.path(), DatasetFormat::Crestereo);
    assert_eq!(ds.len(), 1);
    let s = ds.sample(0).unwrap();
    assert_eq!((s.left, s.right), (l, r));
    assert_disp_eq(&s.disp_left, &disp(2.0));
    assert_disp_eq(s.disp_right.as_ref().unwrap(), &disp(3.0));
    assert_eq!(ds.id(0), Some("stereo_trainset/crestereo/tree/a1"));
    let e = ds.sample(1).unwrap_err().to_string();
    assert!(e.contains("out of range"), "{e}");
}

#[test]
fn sceneflow_layout_with_right_disparity() {
    let t = tempfile::tempdir().unwrap();
    sceneflow(&t.path().join("FlyingThings3D"));
    let ds = open(t.path(), DatasetFormat::SceneFlow);
    assert_eq!(ds.len(), 1);
    let s = ds.sample(0).unwrap();
    assert_eq!((s.left, s.right), (rgb(1), rgb(4)));
    assert_disp_eq(&s.disp_left, &disp(1.0));
    assert_disp_eq(s.disp_right.as_ref().unwrap(), &disp(4.0));
    assert_eq!(s.meta.f_px, Some(1050.0));
}

#[test]
fn middlebury_2014_layout_inf_is_invalid_and_calib_is_parsed() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("trainingF/Adirondack");
    // Written by hand as Middlebury does: big-endian is allowed too; inf where unknown.
    let want = middlebury_scene(&dir);
    let ds = open(t.path(), DatasetFormat::Middlebury);
    let s = ds.sample(0).unwrap();
    assert_eq!((s.left.clone(), s.right.clone()), (rgb(5), rgb(6)));
    assert_disp_eq(&s.disp_left, &want);
    // calib.txt's corner-origin cx, as a 0-based pixel centre.
    assert_eq!(
        (s.meta.f_px, s.meta.ndisp, s.meta.cx, s.meta.cy),
        (Some(3997.684), Some(280), Some(1176.228), Some(1011.228))
    );
    assert!((s.meta.baseline_m.unwrap() - 0.193001).abs() < 1e-12);
    assert_eq!(
        s.meta.extra.get("doffs").map(String::as_str),
        Some("131.111")
    );
    assert!(s.valid_left.is_none());
    // A broken calib.txt is an error naming it.
    fs::write(dir.join("calib.txt"), "cam0=[1 2 3]\n").unwrap();
    let e = open_dataset(t.path(), None).err().unwrap().to_string();
    assert!(e.contains("calib.txt") && e.contains("3x3"), "{e}");
}

#[test]
fn eth3d_two_view_layout_applies_the_nocc_mask() {
    let t = tempfile::tempdir().unwrap();
    let dir = mkdir(&t.path().join("two_view_training/delivery_area_1l"));
    write_png_rgb(&dir.join("im0.png"), &rgb(8)).unwrap();
    write_png_rgb(&dir.join("im1.png"), &rgb(9)).unwrap();
    write_disparity_pfm(&dir.join("disp0GT.pfm"), &disp(0.5)).unwrap();
    // 255 = non-occluded, 128 = occluded, 0 = unknown.
    grey8(&dir.join("mask0nocc.png"), |i| [255, 128, 0][i % 3]);
    let ds = open(t.path(), DatasetFormat::Eth3d);
    let s = ds.sample(0).unwrap();
    assert_disp_eq(&s.disp_left, &disp(0.5));
    let want: Vec<bool> = (0..W * H).map(|i| i % 3 == 0 && i != 5).collect();
    assert_eq!(s.valid_left.as_deref(), Some(&want[..]));
    assert_eq!(s.valid_mask(), &want[..]);
}

#[test]
fn eth3d_official_archives_keep_ground_truth_in_a_separate_tree() {
    // two_view_training.7z and two_view_training_gt.7z extracted side by side.
    let t = tempfile::tempdir().unwrap();
    for scene in ["delivery_area_1l", "electro_1l"] {
        let images = mkdir(&t.path().join("two_view_training").join(scene));
        write_png_rgb(&images.join("im0.png"), &rgb(8)).unwrap();
        write_png_rgb(&images.join("im1.png"), &rgb(9)).unwrap();
        fs::write(images.join("calib.txt"), "cam0=[541.764 0 553.869; 0 541.764 232.396; 0 0 1]\ncam1=[541.764 0 553.869; 0 541.764 232.396; 0 0 1]\ndoffs=0\nbaseline=59.9584\nwidth=4\nheight=3\nndisp=64\n").unwrap();
        let gt = mkdir(&t.path().join("two_view_training_gt").join(scene));
        write_disparity_pfm(&gt.join("disp0GT.pfm"), &disp(0.5)).unwrap();
        grey8(&gt.join("mask0nocc.png"), |i| [255, 128, 0][i % 3]);
    }
    // The test images have no ground truth and are not samples.
    let test = mkdir(&t.path().join("two_view_test/lakeside_1l"));
    write_png_rgb(&test.join("im0.png"), &rgb(1)).unwrap();
    write_png_rgb(&test.join("im1.png"), &rgb(1)).unwrap();
    let ds = open(t.path(), DatasetFormat::Eth3d);
    assert_eq!(ds.len(), 2);
    assert_eq!(ds.id(0), Some("two_view_training/delivery_area_1l"));
    let s = ds.sample(0).unwrap();
    assert_eq!((&s.left, &s.right), (&rgb(8), &rgb(9)));
    assert_disp_eq(&s.disp_left, &disp(0.5));
    assert_eq!(s.meta.f_px, Some(541.764));
    // ETH3D's evaluator counts a pixel where the mask is 255.
    let want: Vec<bool> = (0..W * H).map(|i| i % 3 == 0 && i != 5).collect();
    assert_eq!(s.valid_mask(), &want[..]);
    // A GT folder whose images are missing is an error naming the missing file.
    fs::remove_file(t.path().join("two_view_training/electro_1l/im1.png")).unwrap();
    let e = open_dataset(t.path(), None).err().unwrap().to_string();
    assert!(
        e.contains("two_view_training/electro_1l/im1.png") && e.contains("missing"),
        "{e}"
    );
}

#[test]
fn middlebury_2014_perfect_and_imperfect_are_one_scene_read_once() {
    let t = tempfile::tempdir().unwrap();
    let train = t.path().join("Middlebury2014/train");
    middlebury_scene(&train.join("Adirondack-perfect"));
    middlebury_scene(&train.join("Adirondack-imperfect"));
    fs::write(train.join("Adirondack-imperfect/calib.txt"), "cam0=[4161.221 0 1445.577; 0 4161.221 984.686; 0 0 1]\ncam1=[4161.221 0 1654.636; 0 4161.221 984.686; 0 0 1]\ndoffs=209.059\nbaseline=176.252\nwidth=4\nheight=3\nndisp=280\n").unwrap();
    middlebury_scene(&train.join("Jadeplant-perfect"));
    let ids = |variant| {
        let ds = open_dataset_with(
            t.path(),
            None,
            &ReadOptions {
                middlebury_variant: variant,
            },
        )
        .unwrap();
        (0..ds.len())
            .map(|i| ds.id(i).unwrap().to_string())
            .collect::<Vec<_>>()
    };
    // The default is MiddEval3's: the imperfect rectification, where a scene has it.
    assert_eq!(
        ids(MiddleburyVariant::default()),
        [
            "Middlebury2014/train/Adirondack-imperfect",
            "Middlebury2014/train/Jadeplant-perfect"
        ]
    );
    assert_eq!(
        ids(MiddleburyVariant::Perfect),
        [
            "Middlebury2014/train/Adirondack-perfect",
            "Middlebury2014/train/Jadeplant-perfect"
        ]
    );
    assert_eq!(ids(MiddleburyVariant::Both).len(), 3);
    let s = open_dataset(t.path(), None).unwrap().sample(0).unwrap();
    assert_eq!(
        s.meta.extra.get("doffs").map(String::as_str),
        Some("209.059")
    );
    assert_eq!(
        "Both".parse::<MiddleburyVariant>(),
        Ok(MiddleburyVariant::Both)
    );
    assert!(
        "exact"
            .parse::<MiddleburyVariant>()
            .unwrap_err()
            .contains("perfect, imperfect or both")
    );
}

#[test]
fn instereo2k_layout_is_sixteen_bit_times_100() {
    let t = tempfile::tempdir().unwrap();
    // As the archive extracts: train/partN/<pair>/.
    let pair = mkdir(&t.path().join("train/part1/000000"));
    write_png_rgb(&pair.join("left.png"), &rgb(1)).unwrap();
    write_png_rgb(&pair.join("right.png"), &rgb(2)).unwrap();
    // Values that are multiples of 1/100 but not of 1/256: a wrong scale cannot pass.
    let mut want = disp(1.0);
    for (d, _) in want.data.iter_mut().zip(&want.valid).filter(|(_, v)| **v) {
        *d += 0.37;
    }
    write_disparity_png16(&pair.join("left_disp.png"), &want, 100.0).unwrap();
    write_disparity_png16(&pair.join("right_disp.png"), &disp(2.0), 100.0).unwrap();
    let ds = open(t.path(), DatasetFormat::InStereo2k);
    assert_eq!(ds.id(0), Some("train/part1/000000"));
    let s = ds.sample(0).unwrap();
    assert_eq!((&s.left, &s.right), (&rgb(1), &rgb(2)));
    for (g, w) in s.disp_left.data.iter().zip(&want.data) {
        assert!((g - w).abs() < 1e-4, "{g} vs {w}");
    }
    assert_eq!(s.disp_left.valid, want.valid, "0 = invalid");
    assert!(s.disp_right.is_some());
    // An 8-bit disparity PNG is refused, naming the depth expected.
    grey8(&pair.join("left_disp.png"), |i| i as u8);
    let e = ds.sample(0).unwrap_err().to_string();
    assert!(e.contains("left_disp.png") && e.contains("16-bit"), "{e}");
}

#[test]
fn kitti_2015_and_2012_layouts() {
    for (l, r, occ, occ1, noc, fmt) in [
        (
            "image_2",
            "image_3",
            "disp_occ_0",
            Some("disp_occ_1"),
            "disp_noc_0",
            DatasetFormat::Kitti2015,
        ),
        (
            "colored_0",
            "colored_1",
            "disp_occ",
            None,
            "disp_noc",
            DatasetFormat::Kitti2012,
        ),
    ] {
        let t = tempfile::tempdir().unwrap();
        let base = t.path().join("training");
        for f in ["000000_10.png", "000000_11.png", "000001_10.png"] {
            write_png_rgb(
                &mkdir(&base.join(l)).join(f),
                &rgb(f.len() as u8 + f.as_bytes()[5]),
            )
            .unwrap();
            write_png_rgb(&mkdir(&base.join(r)).join(f), &rgb(3)).unwrap();
        }
        for f in ["000000_10.png", "000001_10.png"] {
            write_disparity_png16(
                &mkdir(&base.join(occ)).join(f),
                &disp(f.as_bytes()[5] as f32 - 40.0),
                256.0,
            )
            .unwrap();
            if let Some(o1) = occ1 {
                write_disparity_png16(&mkdir(&base.join(o1)).join(f), &disp(9.0), 256.0).unwrap();
            }
        }
        let mut noc_map = disp(1.0);
        noc_map.valid[0] = false;
        write_disparity_png16(
            &mkdir(&base.join(noc)).join("000001_10.png"),
            &noc_map,
            256.0,
        )
        .unwrap();
        let ds = open(t.path(), fmt);
        assert_eq!(ds.len(), 2, "only the _10 frames have ground truth");
        let s1 = ds.sample(1).unwrap();
        assert_disp_eq(&s1.disp_left, &disp(9.0));
        // KITTI 2015's disp_occ_1 is the second frame's disparity, not the right view's.
        assert!(
            s1.disp_right.is_none(),
            "{fmt}: KITTI has no right-view disparity (disp_occ_1 is frame t+1)"
        );
        let mut want = s1.disp_left.valid.clone();
        want[0] = false;
        assert_eq!(s1.valid_left, Some(want));
        assert!(ds.sample(0).unwrap().valid_left.is_none());
        // The training folder itself is a root too.
        assert_eq!(open_dataset(&base, None).unwrap().len(), 2);
    }
}

#[test]
fn sintel_stereo_layout_with_occlusion_and_out_of_frame_masks() {
    let t = tempfile::tempdir().unwrap();
    let base = t.path().join("training");
    let mut want = disp(2.0);
    want.valid.iter_mut().for_each(|v| *v = true);
    want.data[5] = 0.0;
    want.data[3] = 700.123;
    for d in [
        "clean_left",
        "clean_right",
        "final_left",
        "final_right",
        "disparities",
        "occlusions",
        "outofframe",
    ] {
        let dir = mkdir(&base.join(d).join("alley_1"));
        match d {
            "disparities" => write_disparity_sintel(&dir.join("frame_0001.png"), &want).unwrap(),
            "occlusions" => grey8(
                &dir.join("frame_0001.png"),
                |i| if i == 1 { 255 } else { 0 },
            ),
            "outofframe" => grey8(
                &dir.join("frame_0001.png"),
                |i| if i == 2 { 255 } else { 0 },
            ),
            _ => write_png_rgb(&dir.join("frame_0001.png"), &rgb(d.len() as u8)).unwrap(),
        }
    }
    let ds = open(t.path(), DatasetFormat::Sintel);
    assert_eq!(ds.len(), 1);
    let s = ds.sample(0).unwrap();
    assert_eq!(s.left, rgb("clean_left".len() as u8));
    for (a, b) in s.disp_left.data.iter().zip(&want.data) {
        assert!((a - b).abs() <= 0.5 / 16384.0 + b * 1e-7, "{a} vs {b}");
    }
    let mask: Vec<bool> = (0..W * H).map(|i| i != 1 && i != 2).collect();
    assert_eq!(s.valid_left, Some(mask));
}

#[test]
fn falling_things_depth_becomes_disparity_with_fx_and_6cm() {
    let t = tempfile::tempdir().unwrap();
    let dir = mkdir(&t.path().join("fat/mixed/kitchen_0"));
    let fx = 768.1605834960938;
    fs::write(
        dir.join("_camera_settings.json"),
        format!(r#"{{"camera_settings": [{{"name": "left", "intrinsic_settings": {{"resX": 4, "resY": 3, "fx": {fx}, "fy": {fx}, "cx": 2, "cy": 1.5, "s": 0}}}}, {{"name": "right", "intrinsic_settings": {{"fx": {fx}}}}}]}}"#),
    )
    .unwrap();
    fs::write(dir.join("_object_settings.json"), "{}").unwrap();
    jpeg_pair(&dir, "000000.left.jpg", "000000.right.jpg");
    // Depth in units of 1e-4 m; 0 = no depth.
    let depth: Vec<u16> = (0..W * H)
        .map(|i| if i == 4 { 0 } else { 5000 + 1000 * i as u16 })
        .collect();
    write_png(
        &dir.join("000000.left.depth.png"),
        &Image {
            width: W,
            height: H,
            channels: 1,
            samples: Samples::U16(depth.clone()),
        },
    )
    .unwrap();
    let ds = open(t.path(), DatasetFormat::FallingThings);
    let s = ds.sample(0).unwrap();
    for (i, &z) in depth.iter().enumerate() {
        if z == 0 {
            assert!(!s.disp_left.valid[i]);
        } else {
            let want = fx * 0.06 / (z as f64 * 1e-4);
            assert!(
                (s.disp_left.data[i] as f64 - want).abs() < 1e-4 * want,
                "{} vs {want}",
                s.disp_left.data[i]
            );
        }
    }
    assert_eq!((s.meta.f_px, s.meta.baseline_m), (Some(fx), Some(0.06)));
    assert!(s.disp_right.is_none());
}

fn write_ours(root: &Path, lines: &[String]) {
    fs::write(root.join("manifest.jsonl"), lines.concat()).unwrap();
}

fn our_line(id: &str) -> String {
    format!(
        r#"{{"id":"{id}","category":"primitives","seed":5,"index":0,"files":{{"left":"primitives/{id}_left.png","right":"primitives/{id}_right.png","disp_left":"primitives/{id}_left.disp.exr","disp_right":"primitives/{id}_right.disp.exr","scene":"primitives/{id}.scene.json"}},"width":4,"height":3,"f_px":64.0,"baseline_m":0.1,"cx":2.0,"cy":1.5,"future_field":[1,2]}}"#
    ) + "\n"
}

#[test]
fn our_manifest_layout_and_its_errors() {
    let t = tempfile::tempdir().unwrap();
    let cat = mkdir(&t.path().join("primitives"));
    let meta = left_view_meta(64.0, 0.1);
    for id in ["0000000", "0000001"] {
        write_png_rgb(&cat.join(format!("{id}_left.png")), &rgb(1)).unwrap();
        write_png_rgb(&cat.join(format!("{id}_right.png")), &rgb(2)).unwrap();
        write_disparity_exr(&cat.join(format!("{id}_left.disp.exr")), &disp(0.1), &meta).unwrap();
        write_disparity_exr(&cat.join(format!("{id}_right.disp.exr")), &disp(0.2), &meta).unwrap();
    }
    // A torn last line (a kill mid-append) is not a sample yet.
    let torn = our_line("0000001");
    write_ours(t.path(), &[our_line("0000000"), torn[..40].to_string()]);
    let ds = open(t.path(), DatasetFormat::Stereogen);
    assert_eq!(ds.len(), 1);
    let s = ds.sample(0).unwrap();
    assert_disp_eq(&s.disp_left, &disp(0.1));
    assert_disp_eq(s.disp_right.as_ref().unwrap(), &disp(0.2));
    assert_eq!(
        (s.meta.id.as_str(), s.meta.f_px, s.meta.baseline_m),
        ("0000000", Some(64.0), Some(0.1))
    );
    assert_eq!(s.meta.extra["category"], "primitives");

    // A broken line in the middle is an error naming the manifest and the line.
    write_ours(t.path(), &["{not json\n".to_string(), our_line("0000000")]);
    let e = open_dataset(t.path(), None).err().unwrap().to_string();
    assert!(e.contains("manifest.jsonl") && e.contains("line 1"), "{e}");
    // A file that went missing is an error naming it when the sample is read.
    write_ours(t.path(), &[our_line("0000001")]);
    fs::remove_file(cat.join("0000001_right.png")).unwrap();
    let e = open_dataset(t.path(), None)
        .unwrap()
        .sample(0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("0000001_right.png"), "{e}");
}

/// A line exactly as the generator wrote it before `render_timings` existed.
const LINE_BEFORE_RENDER_TIMINGS: &str = r#"{"id":"0000000","category":"primitives","seed":2026,"index":0,"files":{"left":"primitives/0000000_left.png","right":"primitives/0000000_right.png","disp_left":"primitives/0000000_left.disp.exr","disp_right":"primitives/0000000_right.disp.exr","scene":"primitives/0000000.scene.json"},"width":4,"height":3,"f_px":64.0,"baseline_m":0.1,"cx":2.0,"cy":1.5,"disparity_left":{"min":0.1,"max":13.85,"mean":6.9,"valid_fraction":0.9166666666666666},"disparity_right":null,"render_seconds":4.2,"notes":["object 2: mesh candidate 1"],"sha256":{"disp_left":"00","disp_right":"11","left":"22","right":"33","scene":"44"},"stereogen_version":"0.1.0"}"#;

#[test]
fn a_manifest_from_before_render_timings_still_reads() {
    let t = tempfile::tempdir().unwrap();
    let cat = mkdir(&t.path().join("primitives"));
    write_sample_images(
        &cat,
        "0000000",
        [&rgb(1), &rgb(2)],
        [&disp(0.1), &disp(0.2)],
        &DisparityMeta::default(),
    );
    write_ours(t.path(), &[format!("{LINE_BEFORE_RENDER_TIMINGS}\n")]);
    let entries = Manifest::read(&t.path().join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len(), 1);
    let e = &entries[0];
    assert!(e.render_timings.is_empty());
    assert_eq!(
        (e.seed, e.render_seconds, e.notes.len(), e.disparity_right),
        (2026, 4.2, 1, None)
    );
    // Its scene file has the plain `.scene.json` name of datasets made before `.scene.json.gz`.
    let mut then = SamplePaths::new("primitives", "0000000");
    then.scene = "primitives/0000000.scene.json".into();
    assert_eq!(e.files, then);
    let ds = open(t.path(), DatasetFormat::Stereogen);
    let s = ds.sample(0).unwrap();
    assert_disp_eq(&s.disp_left, &disp(0.1));
    // The manifest's cx = W/2 (continuous) is (W - 1)/2 in SampleMeta's pixel-centre convention.
    assert_eq!((s.meta.cx, s.meta.cy), (Some(1.5), Some(1.0)));
}

#[test]
fn mismatched_sizes_unknown_layouts_and_formats_are_errors() {
    let t = tempfile::tempdir().unwrap();
    let dir = mkdir(&t.path().join("s"));
    write_png_rgb(&dir.join("im0.png"), &rgb(1)).unwrap();
    write_png_rgb(
        &dir.join("im1.png"),
        &RgbImage {
            width: 2,
            height: 2,
            data: vec![0; 12],
        },
    )
    .unwrap();
    write_disparity_pfm(&dir.join("disp0GT.pfm"), &disp(1.0)).unwrap();
    let e = open_dataset(t.path(), None)
        .unwrap()
        .sample(0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("im1.png") && e.contains("2x2") && e.contains("4x3"),
        "{e}"
    );

    let empty = tempfile::tempdir().unwrap();
    let e = detect_format(empty.path()).unwrap_err().to_string();
    assert!(e.contains("cannot recognise"), "{e}");
    let e = open_dataset(empty.path(), Some(DatasetFormat::Crestereo))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("no crestereo samples"), "{e}");
    assert_eq!(
        "KITTI-2015".parse::<DatasetFormat>().unwrap(),
        DatasetFormat::Kitti2015
    );
    assert_eq!(
        "FlyingThings3D".parse::<DatasetFormat>().unwrap(),
        DatasetFormat::SceneFlow
    );
    assert!(
        "cityscapes"
            .parse::<DatasetFormat>()
            .unwrap_err()
            .contains("one of")
    );
    let _: PathBuf = dir.to_path_buf();
}
