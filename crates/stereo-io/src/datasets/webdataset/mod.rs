//! WebDataset: a dataset as POSIX tar shards, the files of one sample consecutive and sharing a
//! key (`<key>.left.png`, `<key>.right.png`, `<key>.disp_left.exr`, `<key>.disp_right.exr`, the
//! maps a source of ours has beside its disparity (`<key>.depth_left.exr`, ...,
//! `<key>.semantic_right.png`), `<key>.json`), which the `webdataset` package, `torchdata` and the Hugging Face `datasets`
//! WebDataset builder read by streaming. Farm-sized datasets are a million small files in the
//! folder layouts; as shards they are a few hundred large ones.
//!
//! ```text
//! <root>/<split>-NNNNNN.tar          the shards of a split, in order
//! <root>/<split>.index.json          its shards with their sample counts and byte sizes
//! <root>/dataset.json                the source's dataset.json, where it has one (ours)
//! ```
//!
//! The index is written last, so a folder without one is an export that did not finish; a shard
//! whose size differs from the index (a copy or export cut short) is named as such when the
//! folder is opened, never read as a smaller dataset.
//!
//! Nothing read is trusted (`index.rs`, `scan.rs`): an index names only files of its own folder,
//! every member's header is checked against the shard's real length, and a key that could name
//! a path outside a folder is refused.

mod index;
pub mod members;
mod read;
mod scan;
mod write;

use serde::{Deserialize, Serialize};

pub use read::{RawSample, ShardReader, WebDataset, decode_member_maps, decode_members};
pub use scan::{ListedMember, scan_shard, scan_tar};
pub use write::{
    CARD_FILE, WebDatasetOptions, WebDatasetSummary, export_webdataset, export_webdataset_selected,
    parse_splits,
};

/// The index of one split: `<root>/<split>.index.json`.
pub const INDEX_SUFFIX: &str = ".index.json";
/// What [`ShardIndex::format`] says.
pub const INDEX_FORMAT: &str = "stereogen-webdataset";
/// The version of the index this build writes and reads.
pub const INDEX_VERSION: u32 = 1;

/// `<root>/<split>.index.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardIndex {
    pub format: String,
    pub version: u32,
    pub split: String,
    /// Samples in all shards of the split.
    pub samples: usize,
    pub shards: Vec<ShardEntry>,
}

/// One shard of a split.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardEntry {
    /// The file name, `<split>-NNNNNN.tar`.
    pub name: String,
    pub samples: usize,
    /// The file's size: a shard of another size is incomplete.
    pub bytes: u64,
}

/// The file name of shard `n` of `split`.
pub fn shard_name(split: &str, n: usize) -> String {
    format!("{split}-{n:06}.tar")
}

/// The member-name suffixes of a sample (after `<key>.`), in the order they are written.
pub mod member {
    pub const LEFT: &str = "left";
    pub const RIGHT: &str = "right";
    pub const DISP_LEFT: &str = "disp_left.exr";
    pub const DISP_RIGHT: &str = "disp_right.exr";
    /// A stricter validity mask of the left view where the source has one: 8-bit PNG, 255 = keep.
    pub const VALID_LEFT: &str = "valid_left.png";
    // The maps beside the disparity, where the source has them, follow (`depth_left.exr`,
    // `depth_right.exr`, `normals_left.exr`, ..., `semantic_right.png`: the manifest's file key
    // and the file's extension, [`crate::datasets::map_member`]), then the SceneSpec and `json`.
    pub const JSON: &str = "json";
}

/// A WebDataset key for an exported sample name: WebDataset splits a member name at the first
/// dot after the last `/` into key and extension, so dots in the name become `_`.
pub(crate) fn sample_key(name: &str) -> String {
    name.replace('.', "_")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_hold_no_dot_and_shards_sort_in_order() {
        assert_eq!(sample_key("tree/0000003"), "tree/0000003");
        assert_eq!(
            sample_key("training_image_2_000000_10.png"),
            "training_image_2_000000_10_png"
        );
        assert!(shard_name("train", 9) < shard_name("train", 10));
        assert_eq!(shard_name("val", 3), "val-000003.tar");
    }
}
