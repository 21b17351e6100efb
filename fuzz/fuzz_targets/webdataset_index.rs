//! Index bytes: the parser accepts only plain shard names of the index's own folder, or gives
//! one error line naming the index; opened beside a real shard, an export whose index parses
//! reads nothing outside its folder.
#![no_main]

use std::path::Path;
use std::sync::OnceLock;

use stereo_io::StereoDataset;
use stereo_io::datasets::webdataset::{ShardIndex, WebDataset};
use stereogen_fuzz::{Limited, check};

#[global_allocator]
static ALLOC: Limited = Limited;

/// A folder holding the seed corpus's real shard, under the name its index gives it.
fn dir() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let shard = include_bytes!("../corpus/tar_shard/export.tar");
        std::fs::write(dir.path().join("train-000000.tar"), shard).unwrap();
        dir
    })
    .path()
}

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let name = "train.index.json";
    if let Some(index) = check(ShardIndex::parse(bytes, Path::new(name)), name) {
        for s in &index.shards {
            let plain = !s.name.is_empty()
                && s.name != "."
                && s.name != ".."
                && !s.name.contains(['/', '\\'])
                && !s.name.chars().any(char::is_control);
            assert!(
                plain,
                "a shard name that is not a plain file name: {:?}",
                s.name
            );
        }
    }
    std::fs::write(dir().join(name), bytes).unwrap();
    let root = dir().to_str().unwrap();
    if let Some(ds) = check(WebDataset::open(dir()), root) {
        for p in ds.shard_paths() {
            assert_eq!(p.parent(), Some(dir()), "a shard outside the folder: {p:?}");
        }
        for i in 0..ds.len() {
            check(ds.read_raw(i), root);
        }
    }
});
