//! Difficulty facts: every rendered sample's manifest line says how much of it is occluded, low in
//! texture and glass or mirror, and its disparity range, measured on the files as written;
//! `stats` shows them per category, and `export --where` selects samples by them.

use std::collections::BTreeSet;
use std::path::Path;

use stereo_io::datasets::stereogen::Difficulty;
use stereogen::dataset::{DatasetLayout, Manifest, ManifestEntry};
use test_support::{
    generate_tiny_preset, output_text as said, run_fails, run_ok as run, stereogen_cmd,
};

fn entries(root: &Path) -> Vec<ManifestEntry> {
    Manifest::read(&DatasetLayout::new(root).manifest()).unwrap()
}

#[test]
fn every_sample_carries_its_difficulty_and_export_selects_by_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = generate_tiny_preset(dir.path(), "reflective", "data", 6, 2);
    let layout = DatasetLayout::new(&data);
    let all = entries(&data);
    let mut glass_or_metal = 0.0;
    for e in &all {
        let d = e.difficulty.expect("every new line carries the facts");
        // Measured on the files as written: the same numbers again from them.
        let left = stereo_io::read_rgb(&layout.abs(&e.files.left)).unwrap();
        let (dl, _) = stereo_io::read_disparity_exr(&layout.abs(&e.files.disp_left)).unwrap();
        let (dr, _) = stereo_io::read_disparity_exr(&layout.abs(&e.files.disp_right)).unwrap();
        let again = Difficulty::measure(&left, &dl, &dr, None);
        assert_eq!(
            (
                again.occluded,
                again.low_texture,
                again.disparity_p1,
                again.disparity_p99
            ),
            (d.occluded, d.low_texture, d.disparity_p1, d.disparity_p99),
            "sample {}",
            e.id
        );
        let summary = e.disparity_left.unwrap();
        assert!((0.0..1.0).contains(&d.occluded), "{d:?}");
        assert!((0.0..=1.0).contains(&d.low_texture), "{d:?}");
        assert!(summary.min <= d.disparity_p1 && d.disparity_p1 <= d.disparity_p99);
        assert!(d.disparity_p99 <= summary.max);
        let share = d
            .transparent_mirror
            .expect("the material-index pass was rendered");
        assert!((0.0..=1.0).contains(&share));
        glass_or_metal += share;
    }
    // The reflective preset's objects are mostly glass and metal.
    assert!(
        glass_or_metal > 0.0,
        "no glass or metal pixel in 6 reflective scenes"
    );

    let o = run(stereogen_cmd(["stats"]).arg(&data));
    let text = said(&o);
    assert!(
        text.contains("difficulty reflective") && text.contains("difficulty all"),
        "{text}"
    );
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("stats.json")).unwrap()).unwrap();
    assert_eq!(stats["difficulty"].as_array().unwrap().len(), 2);

    // --where: the samples below the median occlusion, as WebDataset shards.
    let mut occluded: Vec<f64> = all.iter().map(|e| e.difficulty.unwrap().occluded).collect();
    occluded.sort_by(f64::total_cmp);
    let median = occluded[occluded.len() / 2];
    let expected: BTreeSet<String> = all
        .iter()
        .filter(|e| e.difficulty.unwrap().occluded < median)
        .map(|e| e.id.clone())
        .collect();
    assert!(!expected.is_empty() && expected.len() < all.len());
    let shards = dir.path().join("shards");
    let o = run(stereogen_cmd(["export"])
        .arg(&data)
        .args(["--format", "webdataset", "--out"])
        .arg(&shards)
        .args([
            "--where",
            &format!("occluded < {median} and category == 'reflective'"),
        ]));
    assert!(
        said(&o).contains(&format!("exported {} sample(s)", expected.len())),
        "{}",
        said(&o)
    );
    let read = stereo_io::open_dataset(&shards, None).unwrap();
    let got: BTreeSet<String> = (0..read.len())
        .map(|i| read.sample(i).unwrap().meta.id)
        .collect();
    assert_eq!(got, expected);

    // A bad expression, and a line written before the facts were measured: clear errors.
    // Neither refused export leaves an output folder behind.
    let err = run_fails(
        stereogen_cmd(["export"])
            .arg(&data)
            .args(["--format", "webdataset", "--out"])
            .arg(dir.path().join("x"))
            .args(["--where", "blur < 2"]),
    );
    assert!(err.contains("unknown field \"blur\""), "{err}");
    assert!(!dir.path().join("x").exists());
    let manifest = layout.manifest();
    let text = std::fs::read_to_string(&manifest).unwrap();
    let mut first: serde_json::Value = serde_json::from_str(text.lines().next().unwrap()).unwrap();
    first.as_object_mut().unwrap().remove("difficulty");
    let rest: Vec<&str> = text.lines().skip(1).collect();
    std::fs::write(&manifest, format!("{first}\n{}\n", rest.join("\n"))).unwrap();
    let err = run_fails(
        stereogen_cmd(["export"])
            .arg(&data)
            .args(["--format", "crestereo", "--out"])
            .arg(dir.path().join("y"))
            .args(["--where", "low_texture < 0.5"]),
    );
    assert!(
        err.contains(&format!("sample {} has no low_texture", all[0].id)),
        "{err}"
    );
    assert!(!dir.path().join("y").exists());
}
