//! `manifest.jsonl` — the entry type, its one reader and the appender — lives in stereo-io
//! ([`stereo_io::stereogen`]); re-exported for the generator's modules.

pub use stereo_io::stereogen::{DisparitySummary, Manifest, ManifestContents, ManifestEntry, read_manifest};
