//! `stereogen merge OUT --webdataset DIR` with the real CLI and renderer: a farm rendered in two
//! shards by separate processes is merged straight into WebDataset shards that read back equal
//! to the merged dataset (pixels and disparities exactly) and byte for byte equal to
//! `export --format webdataset` of it; a merge with a problem writes no shard folder; an existing
//! export is kept unless `--force`; a merge killed with SIGKILL while writing its shards is
//! finished by the same command to the bytes of an uninterrupted one.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use stereo_io::{DatasetFormat, open_dataset};
use test_support::files::files_with_bytes as files;
use test_support::{export_cmd, merge_cmd, output_text as text, two_shard_farm};

/// The shard options every merge here uses: one sample a shard, shuffled, two splits.
const SHARDS: [&str; 6] = [
    "--shard-size",
    "1B",
    "--shuffle-seed",
    "3",
    "--splits",
    "train=0.5,val=0.5",
];

/// `merge OUT --webdataset DIR` with [`SHARDS`] and `extra`.
fn merge_into(out: &Path, wds: &Path, extra: &[&str]) -> Command {
    let mut c = merge_cmd(out);
    c.arg("--webdataset").arg(wds).args(SHARDS).args(extra);
    c
}

/// The shards hold every sample of the merged dataset, with its pixels and disparities exactly.
fn assert_same_samples(merged: &Path, wds: &Path) {
    let source = open_dataset(merged, None).unwrap();
    let shards = open_dataset(wds, None).unwrap();
    assert_eq!(source.format(), DatasetFormat::Stereogen);
    assert_eq!(
        (shards.format(), shards.len()),
        (DatasetFormat::WebDataset, source.len())
    );
    let by_id: std::collections::HashMap<String, usize> = (0..source.len())
        .map(|k| (source.sample(k).unwrap().meta.id, k))
        .collect();
    let mut seen = Vec::new();
    for i in 0..shards.len() {
        let got = shards.sample(i).unwrap();
        let k = by_id[&got.meta.id];
        let want = source.sample(k).unwrap();
        assert_eq!((&got.left, &got.right), (&want.left, &want.right), "{k}");
        assert_eq!(got.disp_left, want.disp_left, "{k}");
        assert_eq!(got.disp_right, want.disp_right, "{k}");
        seen.push(k);
    }
    seen.sort_unstable();
    assert_eq!(
        seen,
        (0..source.len()).collect::<Vec<_>>(),
        "each sample once"
    );
}

#[test]
fn a_merged_farm_is_written_as_shards_equal_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = two_shard_farm(dir.path(), 4);

    // A problem (a missing file) stops the merge before any shard is written.
    let broken = dir.path().join("broken");
    let o = Command::new("cp").arg("-a").arg(&out).arg(&broken).output();
    assert!(o.unwrap().status.success());
    let shard1 = broken.join("shards/0001-of-0002");
    let first = stereogen::dataset::Manifest::read(&shard1.join("manifest.jsonl")).unwrap()[0]
        .files
        .left
        .clone();
    std::fs::remove_file(shard1.join(&first)).unwrap();
    let broken_wds = dir.path().join("broken-wds");
    let o = merge_into(&broken, &broken_wds, &[]).output().unwrap();
    assert!(
        !o.status.success() && text(&o).contains("is missing") && text(&o).contains("problem(s)"),
        "{}",
        text(&o)
    );
    assert!(
        !broken_wds.exists(),
        "a merge with problems writes no shards"
    );
    assert!(!broken.join("manifest.jsonl").exists());

    let wds = dir.path().join("wds");
    let o = merge_into(&out, &wds, &[]).output().unwrap();
    let said = text(&o);
    assert!(o.status.success(), "{said}");
    assert!(
        said.contains("merged 4 samples of 2 shards")
            && said.contains("wrote 4 sample(s) as 4 WebDataset shard(s)"),
        "{said}"
    );
    for name in ["train.index.json", "val.index.json", "dataset.json"] {
        assert!(wds.join(name).is_file(), "{name}");
    }
    assert_same_samples(&out, &wds);

    // The same shards as `export --format webdataset` of the merged dataset, byte for byte.
    let exported = dir.path().join("exported");
    let o = export_cmd(&out, "webdataset", &exported)
        .args(SHARDS)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(files(&wds) == files(&exported), "merge and export differ");

    // A finished export is kept unless --force.
    let o = merge_into(&out, &wds, &[]).output().unwrap();
    assert!(
        !o.status.success() && text(&o).contains("--force"),
        "{}",
        text(&o)
    );
    let o = merge_into(&out, &wds, &["--force"]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(files(&wds) == files(&exported));

    // The farm's own folders are refused as the shard folder, before anything is merged.
    for bad in [out.clone(), out.join("shards/wds")] {
        let o = merge_into(&out, &bad, &["--force"]).output().unwrap();
        assert!(
            !o.status.success() && text(&o).contains("a folder of their own"),
            "{}",
            text(&o)
        );
    }
    // Shard options without a shard folder are an error, not ignored.
    let o = merge_cmd(&out).args(SHARDS).output().unwrap();
    assert!(
        !o.status.success() && text(&o).contains("need --webdataset"),
        "{}",
        text(&o)
    );
}

/// Grows a two-shard farm of samples 0 and 1 to `n` samples: each new sample of shard `k` is
/// sample `k`'s files hard-linked under the new index's id and its manifest line with the new
/// index, so a merge takes it as rendered (same bytes, same checksums).
fn grow_farm(out: &Path, n: u64) {
    for k in 0..2u64 {
        let shard = out.join(format!("shards/{k:04}-of-0002"));
        let manifest = shard.join("manifest.jsonl");
        let text = std::fs::read_to_string(&manifest).unwrap();
        let line: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
        let old_id = format!("{k:07}");
        assert_eq!(line["id"], old_id.as_str());
        let mut lines = text.clone();
        for i in (k..n).step_by(2).skip(1) {
            let id = format!("{i:07}");
            let mut e = line.clone();
            e["index"] = i.into();
            e["id"] = id.as_str().into();
            for (_, rel) in e["files"].as_object_mut().unwrap() {
                let new = rel.as_str().unwrap().replace(&old_id, &id);
                std::fs::hard_link(shard.join(rel.as_str().unwrap()), shard.join(&new)).unwrap();
                *rel = new.into();
            }
            lines.push_str(&format!("{e}\n"));
        }
        std::fs::write(&manifest, lines).unwrap();
        let info = shard.join("shard.json");
        let mut json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&info).unwrap()).unwrap();
        json["count"] = n.into();
        std::fs::write(&info, json.to_string()).unwrap();
    }
}

#[test]
fn a_merge_killed_while_writing_shards_is_finished_by_the_same_command() {
    let dir = tempfile::tempdir().unwrap();
    let out = two_shard_farm(dir.path(), 2);
    grow_farm(&out, 400);
    let clean = dir.path().join("clean");
    let t0 = Instant::now();
    let o = merge_into(&out, &clean, &[]).output().unwrap();
    eprintln!(
        "farm_webdataset: merge --webdataset of 400 samples into 400 shards took {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(
        o.status.success() && text(&o).contains("wrote 400 sample(s) as 400 WebDataset shard(s)"),
        "{}",
        text(&o)
    );

    let wds = dir.path().join("killed");
    let mut child = merge_into(&out, &wds, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let shard = wds.join("train-000002.tar");
    while !shard.exists() && start.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(1));
    }
    child.kill().unwrap(); // SIGKILL: no chance to clean up
    child.wait().unwrap();
    assert!(shard.exists(), "three shards written before the kill");
    assert!(
        !wds.join("val.index.json").exists(),
        "killed before the end"
    );

    let o = merge_into(&out, &wds, &[]).output().unwrap();
    let said = text(&o);
    assert!(o.status.success(), "{said}");
    assert!(
        said.contains("wrote 400 sample(s)") && !said.contains("(0 kept from an interrupted run)"),
        "{said}"
    );
    assert!(
        files(&wds) == files(&clean),
        "the resumed shards differ from an uninterrupted merge's"
    );
    assert_same_samples(&out, &wds);
}
