//! `manifest.jsonl` and its sidecar logs `failures.jsonl` and `skipped_assets.jsonl` — the record
//! types, their one reader and appender each — live in stereo-io
//! ([`stereo_io::datasets::stereogen`]); re-exported for the generator's modules.

pub use stereo_io::datasets::stereogen::{
    FailureRecord, SkippedAssetRecord, append_sidecar, read_failures, read_skipped_assets,
    retain_sidecar,
};
pub use stereo_io::{DisparitySummary, Manifest, ManifestContents, ManifestEntry, read_manifest};
