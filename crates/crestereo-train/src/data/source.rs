//! The training datasets: opened (a WebDataset source kept for streaming), named and weighted.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use stereo_io::{DatasetFormat, StereoDataset, StereoSample, WebDataset, open_dataset};

use super::stream_order::StreamLayout;
use crate::config::{DatasetEntry, StreamSettings};

/// The training datasets, opened, with their normalised weights.
pub struct MixedSource {
    pub datasets: Vec<Box<dyn StereoDataset>>,
    pub names: Vec<String>,
    pub weights: Vec<f64>,
    /// The WebDataset sources (the same data as `datasets[i]`), which can be streamed.
    pub webdatasets: Vec<Option<Arc<WebDataset>>>,
}

/// A WebDataset shared between the streaming readers and random access.
struct SharedWebDataset(Arc<WebDataset>);

impl StereoDataset for SharedWebDataset {
    fn format(&self) -> DatasetFormat {
        self.0.format()
    }
    fn root(&self) -> &Path {
        self.0.root()
    }
    fn len(&self) -> usize {
        self.0.len()
    }
    fn id(&self, index: usize) -> Option<&str> {
        self.0.id(index)
    }
    fn sample(&self, index: usize) -> stereo_io::Result<StereoSample> {
        self.0.sample(index)
    }
}

impl MixedSource {
    pub fn open(entries: &[DatasetEntry]) -> Result<Self> {
        let mut datasets = Vec::new();
        let mut names = Vec::new();
        let mut webdatasets = Vec::new();
        for (i, e) in entries.iter().enumerate() {
            let key = format!("datasets[{i}]");
            let format = e.format.or_else(|| stereo_io::detect_format(&e.path).ok());
            let ds: Box<dyn StereoDataset> = if format == Some(DatasetFormat::WebDataset) {
                let shards = WebDataset::open(&e.path)
                    .with_context(|| format!("{key}: cannot open {}", e.path.display()))?;
                if shards.is_empty() {
                    bail!("{key}: {} holds no samples", e.path.display());
                }
                let shards = Arc::new(shards);
                webdatasets.push(Some(shards.clone()));
                Box::new(SharedWebDataset(shards))
            } else {
                webdatasets.push(None);
                open_data(&e.path, e.format, &key)?
            };
            names.push(format!(
                "{} ({}, {} samples)",
                e.path.display(),
                ds.format(),
                ds.len()
            ));
            datasets.push(ds);
        }
        let total: f64 = entries.iter().map(|e| e.weight).sum();
        let weights = entries.iter().map(|e| e.weight / total).collect();
        Ok(Self {
            datasets,
            names,
            weights,
            webdatasets,
        })
    }

    /// How each dataset's epochs are ordered under `settings`: streamed (a WebDataset source,
    /// `settings.streams` > 0) or `None` (a full shuffle, read by random access).
    pub fn stream_layouts(&self, settings: &StreamSettings) -> Vec<Option<StreamLayout>> {
        (0..self.datasets.len())
            .map(|d| {
                let ws = self.webdatasets.get(d)?.as_ref()?;
                (settings.streams > 0).then(|| StreamLayout {
                    shard_samples: ws.shard_samples(),
                    streams: settings.streams,
                    buffer: settings.shuffle_buffer.max(1),
                })
            })
            .collect()
    }
}

/// Opens a dataset that must hold samples; `key` names it in errors (`datasets[0]`, `--data`).
pub fn open_data(
    path: &Path,
    format: Option<stereo_io::DatasetFormat>,
    key: &str,
) -> Result<Box<dyn StereoDataset>> {
    let ds = open_dataset(path, format)
        .with_context(|| format!("{key}: cannot open {}", path.display()))?;
    if ds.is_empty() {
        bail!("{key}: {} holds no samples", path.display());
    }
    Ok(ds)
}
