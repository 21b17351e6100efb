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
    /// Opens the training datasets; a WebDataset export yields the splits of its entry (by
    /// default `train`, see [`choose_splits`]), never its held-out ones.
    pub fn open(entries: &[DatasetEntry]) -> Result<Self> {
        let mut datasets = Vec::new();
        let mut names = Vec::new();
        let mut webdatasets = Vec::new();
        for (i, e) in entries.iter().enumerate() {
            let key = format!("datasets[{i}]");
            let ds: Box<dyn StereoDataset> = if is_webdataset(&e.path, e.format) {
                let shards = Arc::new(open_webdataset(
                    &e.path,
                    e.splits.as_deref(),
                    SplitUse::Train,
                    &key,
                )?);
                webdatasets.push(Some(shards.clone()));
                Box::new(SharedWebDataset(shards))
            } else {
                webdatasets.push(None);
                open_data(
                    &e.path,
                    e.format,
                    e.splits.as_deref(),
                    SplitUse::Train,
                    &key,
                )?
            };
            names.push(describe(ds.as_ref(), webdatasets[i].as_deref()));
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

/// What data is read for, which decides the split a WebDataset export gives when none is named.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SplitUse {
    /// `train` where the export has it, else its only split; several others: an error asking.
    Train,
    /// The export's only split, else `val`, else `test`; else an error asking.
    Eval,
}

/// Whether `path` is read as a WebDataset export: `format` says so, or, absent, the folder is
/// recognised as one.
pub fn is_webdataset(path: &Path, format: Option<DatasetFormat>) -> bool {
    format.or_else(|| stereo_io::detect_format(path).ok()) == Some(DatasetFormat::WebDataset)
}

/// The splits of the WebDataset export at `path` to read for `purpose`, sorted by name, each
/// once: those `requested` (a name the export lacks is an error listing its splits), else the
/// default of `purpose` ([`SplitUse`]). `key` names the entry in errors (`datasets[0]`).
pub fn choose_splits(
    path: &Path,
    requested: Option<&[String]>,
    purpose: SplitUse,
    key: &str,
) -> Result<Vec<String>> {
    let available = WebDataset::split_names(path)
        .with_context(|| format!("{key}: cannot open {}", path.display()))?;
    let listed = available.join(", ");
    if let Some(requested) = requested {
        if requested.is_empty() {
            bail!(
                "{key}: no split named for {} (its splits: {listed})",
                path.display()
            );
        }
        if let Some(unknown) = requested.iter().find(|r| !available.contains(r)) {
            bail!(
                "{key}: {} has no split {unknown:?}; its splits: {listed}",
                path.display()
            );
        }
        return Ok(available
            .into_iter()
            .filter(|a| requested.contains(a))
            .collect());
    }
    let preferred: &[&str] = match purpose {
        SplitUse::Train => &["train"],
        SplitUse::Eval => &["val", "test"],
    };
    if let [only] = available.as_slice() {
        return Ok(vec![only.clone()]);
    }
    if let Some(p) = preferred.iter().find(|p| available.iter().any(|a| a == *p)) {
        return Ok(vec![p.to_string()]);
    }
    let (what, wanted) = match purpose {
        SplitUse::Train => ("train on", "no `train` split"),
        SplitUse::Eval => ("evaluate", "no `val` or `test` split"),
    };
    bail!(
        "{key}: {} is a WebDataset export with splits {listed} and {wanted}: name the split(s) to {what}, DIR:webdataset:SPLIT[,SPLIT] (`splits = [...]` in the config)",
        path.display()
    )
}

/// Opens the splits of the WebDataset export at `path` chosen by [`choose_splits`]; it must hold
/// samples.
pub fn open_webdataset(
    path: &Path,
    requested: Option<&[String]>,
    purpose: SplitUse,
    key: &str,
) -> Result<WebDataset> {
    let splits = choose_splits(path, requested, purpose, key)?;
    let shards = WebDataset::open_splits(path, &splits)
        .with_context(|| format!("{key}: cannot open {}", path.display()))?;
    if shards.is_empty() {
        bail!(
            "{key}: {} holds no samples in split {}",
            path.display(),
            splits.join(", ")
        );
    }
    Ok(shards)
}

/// How a dataset is named in the log: `DIR (FORMAT, N samples)`, with a WebDataset's splits.
pub fn describe(ds: &dyn StereoDataset, webdataset: Option<&WebDataset>) -> String {
    let splits = webdataset.map_or(String::new(), |w| {
        let s = w.splits();
        let word = if s.len() == 1 { "split" } else { "splits" };
        format!(" {word} {}", s.join(", "))
    });
    format!(
        "{} ({}{splits}, {} samples)",
        ds.root().display(),
        ds.format(),
        ds.len()
    )
}

/// Opens a dataset that must hold samples; `key` names it in errors (`datasets[0]`, `--data`).
/// A WebDataset export (its splits logged) yields the `splits` named, else those [`choose_splits`] picks for
/// `purpose`; naming splits of another layout is an error.
pub fn open_data(
    path: &Path,
    format: Option<stereo_io::DatasetFormat>,
    splits: Option<&[String]>,
    purpose: SplitUse,
    key: &str,
) -> Result<Box<dyn StereoDataset>> {
    if is_webdataset(path, format) {
        let shards = open_webdataset(path, splits, purpose, key)?;
        // Which part of an export is read is a choice made here: always said.
        tracing::info!("{key}: {}", describe(&shards, Some(&shards)));
        return Ok(Box::new(shards));
    }
    if splits.is_some() {
        bail!(
            "{key}: splits are named for {}, which is not a WebDataset export (they choose among its <split>.index.json)",
            path.display()
        );
    }
    let ds = open_dataset(path, format)
        .with_context(|| format!("{key}: cannot open {}", path.display()))?;
    if ds.is_empty() {
        bail!("{key}: {} holds no samples", path.display());
    }
    Ok(ds)
}
