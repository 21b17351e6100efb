//! WebDataset shard bytes: the tar scanner lists members that lie inside the bytes with keys
//! that stay inside a folder, or gives one error line naming the shard; a shard that lists is
//! then opened as an export (with an index that agrees with it) and every sample read by
//! seeking, read by streaming and decoded, each within the limits or one error line.
#![no_main]

use std::io::Cursor;
use std::path::Path;
use std::sync::OnceLock;

use stereo_io::StereoDataset;
use stereo_io::datasets::webdataset::{INDEX_FORMAT, INDEX_VERSION, WebDataset, scan_tar};
use stereogen_fuzz::{Limited, check};

#[global_allocator]
static ALLOC: Limited = Limited;

const SHARD: &str = "train-000000.tar";

/// One folder for every run: each input rewrites its shard and index.
fn dir() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| tempfile::tempdir().unwrap()).path()
}

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let len = bytes.len() as u64;
    let Some(members) = check(scan_tar(Cursor::new(bytes), len, Path::new(SHARD)), SHARD) else {
        return;
    };
    for m in &members {
        assert!(
            m.offset + m.size <= len,
            "a member past the end listed: {m:?}"
        );
        assert!(
            !m.key.starts_with('/') && !m.key.split('/').any(|c| c == ".." || c.is_empty()),
            "a key leaving its folder listed: {m:?}"
        );
    }
    let samples = members
        .iter()
        .enumerate()
        .filter(|(i, m)| *i == 0 || members[i - 1].key != m.key)
        .count();
    let index = format!(
        r#"{{"format":"{INDEX_FORMAT}","version":{INDEX_VERSION},"split":"train","samples":{samples},"shards":[{{"name":"{SHARD}","samples":{samples},"bytes":{len}}}]}}"#
    );
    std::fs::write(dir().join(SHARD), bytes).unwrap();
    std::fs::write(dir().join("train.index.json"), index).unwrap();
    let Some(ds) = check(WebDataset::open(dir()), SHARD) else {
        return;
    };
    assert_eq!(
        ds.len(),
        samples,
        "the export lists other samples than the scan"
    );
    let mut stream = ds.shard_reader(0).unwrap();
    for i in 0..ds.len() {
        let seeked = check(ds.read_raw(i), SHARD);
        let streamed = check(stream.read(&ds, i), SHARD);
        assert_eq!(
            seeked, streamed,
            "seeking and streaming read sample {i} differently"
        );
        check(ds.sample(i), SHARD);
    }
});
