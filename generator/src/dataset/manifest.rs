//! `manifest.jsonl` — the entry type, its one reader and the appender — lives in stereo-io
//! ([`stereo_io::datasets::stereogen`]); re-exported for the generator's modules.

pub use stereo_io::{DisparitySummary, Manifest, ManifestContents, ManifestEntry, read_manifest};
