//! The on-disk dataset: layout, manifest, finishing a sample atomically, and resumable generation.

pub mod export;
pub mod generate;
pub mod layout;
pub mod manifest;
pub mod sample;

pub use generate::{GenerateOptions, GenerateSummary, generate};
pub use layout::{DatasetInfo, DatasetLayout, SamplePaths};
pub use manifest::{DisparitySummary, Manifest, ManifestEntry};
pub use sample::finalize_sample;
