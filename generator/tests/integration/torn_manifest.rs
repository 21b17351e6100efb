//! The one rule for an unfinished last line of `manifest.jsonl`, as every consumer sees it: a
//! dataset written through the generator's layout and appender, with half a line appended (a
//! reader racing `generate`, or an append torn by a kill). Readers leave the line out; only the
//! appender's open cuts it off.

use std::path::Path;

use stereo_io::{DisparityMap, DisparityMeta, RgbImage};
use stereogen::assets::AssetIndex;
use stereogen::dataset::export::{ExportOptions, export};
use stereogen::dataset::{CreateDataset, DatasetLayout, Manifest, ManifestEntry, read_manifest};
use stereogen::plan::{Recipe, plan_scene};
use stereogen::validate::StatsOptions;

const W: usize = 16;
const H: usize = 12;
const FINISHED: u64 = 3;

fn image(seed: u8) -> RgbImage {
    test_support::io_fixtures::patterned_rgb(W, H, 13, seed)
}

fn disparity(d: f32) -> DisparityMap {
    DisparityMap {
        width: W,
        height: H,
        data: vec![d; W * H],
        valid: vec![true; W * H],
    }
}

/// `FINISHED` samples through the layout and the appender, then a torn line; returns it.
fn dataset_with_torn_line(root: &Path) -> String {
    let recipe = Recipe::preset("crestereo").unwrap();
    let layout = DatasetLayout::new(root);
    layout.open_or_create(&recipe, 7).unwrap();
    let (mut manifest, done) = Manifest::open(&layout.manifest()).unwrap();
    assert!(done.entries.is_empty());
    let mut last = String::new();
    for index in 0..=FINISHED {
        let spec = plan_scene(&recipe, &AssetIndex::default(), 7, index);
        let files = layout.sample_paths(&spec.category, &spec.id);
        std::fs::create_dir_all(root.join(&spec.category)).unwrap();
        stereo_io::write_png_rgb(&layout.abs(&files.left), &image(index as u8)).unwrap();
        stereo_io::write_png_rgb(&layout.abs(&files.right), &image(100 + index as u8)).unwrap();
        stereo_io::write_disparity_exr(
            &layout.abs(&files.disp_left),
            &disparity(5.0),
            &DisparityMeta::default(),
        )
        .unwrap();
        stereo_io::write_disparity_exr(
            &layout.abs(&files.disp_right),
            &disparity(5.0),
            &DisparityMeta::default(),
        )
        .unwrap();
        std::fs::write(layout.abs(&files.scene), spec.to_json()).unwrap();
        let entry = ManifestEntry {
            id: spec.id.clone(),
            category: spec.category.clone(),
            seed: 7,
            index,
            files,
            width: W as u32,
            height: H as u32,
            f_px: 20.0,
            baseline_m: 0.1,
            cx: W as f64 / 2.0,
            cy: H as f64 / 2.0,
            disparity_left: None,
            disparity_right: None,
            difficulty: None,
            render_seconds: 1.0,
            render_timings: [("render_color_left".to_string(), 0.5)].into(),
            notes: vec![],
            instances: Vec::new(),
            sha256: Default::default(),
            stereogen_version: "test".into(),
        };
        if index < FINISHED {
            manifest.append(&entry).unwrap();
        } else {
            last = serde_json::to_string(&entry).unwrap();
        }
    }
    // Half of the next line, as a reader sees an append in progress.
    let torn = &last[..last.len() / 2];
    let mut text = std::fs::read_to_string(layout.manifest()).unwrap();
    text.push_str(torn);
    std::fs::write(layout.manifest(), text).unwrap();
    torn.to_string()
}

#[test]
fn every_reader_leaves_an_unfinished_last_line_out_and_only_the_appender_cuts_it() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    let torn = dataset_with_torn_line(&root);
    let manifest = root.join("manifest.jsonl");

    let contents = read_manifest(&manifest).unwrap();
    assert_eq!(
        (contents.entries.len() as u64, contents.unfinished_bytes),
        (FINISHED, torn.len() as u64)
    );
    assert_eq!(contents.entries[0].render_timings["render_color_left"], 0.5);

    let ds = stereo_io::open_dataset(&root, None).unwrap();
    assert_eq!(ds.len() as u64, FINISHED, "stereo-io reader");

    let report = stereogen::validate::compute(&StatsOptions::new(&root)).unwrap();
    assert_eq!(report.samples as u64, FINISHED, "stats");

    let sheet = tmp.path().join("sheet.png");
    assert_eq!(
        stereogen::validate::contact_sheet::write_contact_sheet(&root, 10, 2, &sheet).unwrap()
            as u64,
        FINISHED,
        "sheet"
    );

    let out = tmp.path().join("cre");
    let opts = ExportOptions {
        dataset: root.clone(),
        from: None,
        format: "crestereo".parse().unwrap(),
        out: out.clone(),
        jpeg_quality: None,
        jpeg_chroma: Default::default(),
        middlebury_variant: Default::default(),
        shards: Default::default(),
        selection: None,
    };
    assert_eq!(export(&opts).unwrap().samples() as u64, FINISHED, "export");
    assert_eq!(
        stereo_io::open_dataset(&out, None).unwrap().len() as u64,
        FINISHED
    );

    // None of the readers touched the file; the appender's open (generate resuming) cuts the
    // torn line, so the next append starts on a line of its own.
    assert!(std::fs::read_to_string(&manifest).unwrap().ends_with(&torn));
    let (_, done) = Manifest::open(&manifest).unwrap();
    assert_eq!(
        (done.entries.len() as u64, done.unfinished_bytes),
        (FINISHED, torn.len() as u64)
    );
    let text = std::fs::read_to_string(&manifest).unwrap();
    assert!(
        text.ends_with('\n') && text.lines().count() as u64 == FINISHED,
        "{text}"
    );
}
