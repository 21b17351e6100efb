//! The on-disk dataset: layout, manifest, finishing a sample atomically, and resumable generation.

pub mod card;
pub mod curate;
pub mod export;
pub mod generate;
pub mod generate_command;
pub mod layout;
pub mod lock;
pub mod manifest;
pub mod merge;
pub mod sample;
pub mod sample_maps;
pub mod scene_file;
pub mod select;
pub mod shard;
pub mod status;

pub use generate::{GenerateOptions, GenerateSummary, generate};
pub use generate_command::{GenerateCommand, RecipeArgs, RuntimeArgs, TaskArgs};
pub use layout::{CreateDataset, DatasetInfo, DatasetLayout, SamplePaths};
pub use manifest::{DisparitySummary, Manifest, ManifestContents, ManifestEntry, read_manifest};
pub use sample::finalize_sample;
pub use scene_file::{read_scene_spec, write_scene_spec};
