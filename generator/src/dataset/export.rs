//! `stereogen export`: a dataset in another trainer's layout, or as WebDataset tar shards. The
//! source is ours or any layout stereo-io reads; the writing is stereo-io's
//! ([`stereo_io::datasets::write`] describes the layouts, what is linked and what is dropped;
//! [`stereo_io::datasets::webdataset`] the shards).

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use super::select::Selection;

use anyhow::{Context, bail};
use stereo_io::{
    ChromaSampling, DatasetFormat, ImageEncoding, JpegOptions, MiddleburyVariant, ReadOptions,
    SampleSelection, WebDatasetOptions, WebDatasetSummary, WritableFormat, WriteSummary,
};

/// What `export --format` names: a folder layout, or WebDataset shards.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    Layout(WritableFormat),
    WebDataset,
}

impl FromStr for ExportFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s.eq_ignore_ascii_case("webdataset") || s.eq_ignore_ascii_case("wds") {
            return Ok(Self::WebDataset);
        }
        s.parse::<WritableFormat>()
            .map(Self::Layout)
            .map_err(|e| format!("{e}, or webdataset"))
    }
}

impl fmt::Display for ExportFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Layout(layout) => layout.fmt(f),
            Self::WebDataset => f.write_str("webdataset"),
        }
    }
}

/// `--splits train=0.98,val=0.02`: split names and fractions (see [`stereo_io::parse_splits`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SplitFractions(pub Vec<(String, f64)>);

impl FromStr for SplitFractions {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        stereo_io::parse_splits(s).map(Self)
    }
}

impl fmt::Display for SplitFractions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (name, fraction)) in self.0.iter().enumerate() {
            let sep = if i == 0 { "" } else { "," };
            write!(f, "{sep}{name}={fraction}")?;
        }
        Ok(())
    }
}

/// The shard options of `export --format webdataset`, `merge --webdataset` and
/// `farm --webdataset`, typed once (flattened into each command).
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct WebDatasetArgs {
    /// WebDataset: close a shard once it holds this much (e.g. 1GiB, 500MB).
    #[arg(long, value_name = "SIZE", default_value = "1GiB", value_parser = parse_bytes)]
    pub shard_size: u64,
    /// WebDataset: seeds the order of the samples across shards.
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub shuffle_seed: u64,
    /// WebDataset: split names and fractions, e.g. train=0.98,val=0.02.
    #[arg(long, value_name = "NAME=FRACTION,...", default_value = "train=1")]
    pub splits: SplitFractions,
    /// Only the samples whose manifest line matches, e.g. 'occluded < 0.2 and low_texture < 0.5'
    /// (conditions FIELD OP VALUE joined by `and`; fields: occluded, low_texture,
    /// transparent_mirror, disparity_p1, disparity_p99, disparity_min, disparity_max, disparity_mean, valid, index,
    /// render_seconds, category == 'NAME'). Our datasets only: the facts are their manifest's.
    #[arg(long = "where", value_name = "EXPR", value_parser = parse_selection)]
    pub selection: Option<Selection>,
}

fn parse_selection(text: &str) -> Result<Selection, String> {
    text.parse()
}

impl Default for WebDatasetArgs {
    fn default() -> Self {
        let d = WebDatasetOptions::default();
        Self {
            shard_size: d.shard_bytes,
            shuffle_seed: d.shuffle_seed,
            splits: SplitFractions(d.splits),
            selection: None,
        }
    }
}

impl WebDatasetArgs {
    /// The writer's options (`force`: replace an export already in the output folder).
    pub fn options(&self, force: bool) -> WebDatasetOptions {
        WebDatasetOptions {
            shard_bytes: self.shard_size,
            shuffle_seed: self.shuffle_seed,
            splits: self.splits.0.clone(),
            force,
        }
    }

    /// Whether any option differs from its default (they mean nothing without shards to write).
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// The options as a command line gives them (every one, so a job file says what it writes).
    pub fn to_args(&self) -> Vec<String> {
        let mut a = vec![
            "--shard-size".into(),
            self.shard_size.to_string(),
            "--shuffle-seed".into(),
            self.shuffle_seed.to_string(),
            "--splits".into(),
            self.splits.to_string(),
        ];
        if let Some(s) = &self.selection {
            a.extend(["--where".into(), s.to_string()]);
        }
        a
    }
}

/// What an export wrote.
#[derive(Debug, Clone)]
pub enum ExportSummary {
    Layout {
        format: WritableFormat,
        written: WriteSummary,
    },
    Shards(WebDatasetSummary),
}

impl ExportSummary {
    /// Samples written.
    pub fn samples(&self) -> usize {
        match self {
            Self::Layout { written, .. } => written.samples,
            Self::Shards(s) => s.samples,
        }
    }
}

/// A size such as `1GiB`, `500MB`, `65536`: bytes, with an optional decimal (kB, MB, GB, TB) or
/// binary (KiB, MiB, GiB, TiB) unit.
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let unit_bytes: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "kb" => 1_000,
        "mb" => 1_000_000,
        "gb" => 1_000_000_000,
        "tb" => 1_000_000_000_000,
        "kib" => 1 << 10,
        "mib" => 1 << 20,
        "gib" => 1 << 30,
        "tib" => 1 << 40,
        other => {
            return Err(format!(
                "{s:?}: unknown unit {other:?} (B, kB, MB, GB, KiB, MiB, GiB, ...)"
            ));
        }
    };
    let value: f64 = number
        .parse()
        .map_err(|_| format!("{s:?} is not a size such as 1GiB or 500MB"))?;
    let bytes = value * unit_bytes as f64;
    if !(1.0..=u64::MAX as f64).contains(&bytes) {
        return Err(format!("{s:?}: a size of at least 1 byte"));
    }
    Ok(bytes as u64)
}

#[derive(Debug, Clone)]
pub struct ExportOptions {
    pub dataset: PathBuf,
    /// The source's layout; recognised from its folder when `None`.
    pub from: Option<DatasetFormat>,
    pub format: ExportFormat,
    pub out: PathBuf,
    /// CREStereo only: re-encode every image as a JPEG of this quality (else source JPEGs are
    /// linked and other images encoded at quality 95).
    pub jpeg_quality: Option<u8>,
    /// CREStereo only: the chroma sampling of the JPEGs written.
    pub jpeg_chroma: ChromaSampling,
    /// Which rectification of a Middlebury 2014 source is read.
    pub middlebury_variant: MiddleburyVariant,
    /// WebDataset only: shard size, shuffle seed, splits, replacing an existing export.
    pub shards: WebDatasetOptions,
    /// Only the samples of our dataset whose manifest line matches (`--where`).
    pub selection: Option<Selection>,
}

/// The ids of the samples of our dataset at `root` that `selection` takes.
fn select(root: &std::path::Path, selection: &Selection) -> anyhow::Result<SampleSelection> {
    let layout = super::DatasetLayout::new(root);
    let entries = super::read_manifest(&layout.manifest())
        .with_context(|| {
            format!(
                "--where reads the facts of our manifest: {} is not a stereogen dataset",
                root.display()
            )
        })?
        .entries;
    let total = entries.len();
    let kept = selection.filter(entries)?;
    if kept.is_empty() {
        bail!("--where {selection:?}: none of the {total} samples matches");
    }
    tracing::info!("--where {selection}: {} of {total} samples", kept.len());
    Ok(SampleSelection {
        ids: kept.into_iter().map(|e| e.id).collect(),
        description: selection.to_string(),
    })
}

/// Writes every sample of `opts.dataset` into `opts.out` in `opts.format`: a layout with
/// `stereogen_samples.tsv` mapping the exported samples back to the source's, or shards with an
/// index per split and a dataset card (`README.md`, [`super::card`]).
pub fn export(opts: &ExportOptions) -> anyhow::Result<ExportSummary> {
    let images = match (opts.jpeg_quality, opts.jpeg_chroma) {
        (None, ChromaSampling::Full) => ImageEncoding::Lossless,
        (quality, chroma) => ImageEncoding::JpegWith(JpegOptions {
            quality: quality.unwrap_or(JpegOptions::default().quality),
            chroma,
        }),
    };
    let read = ReadOptions {
        middlebury_variant: opts.middlebury_variant,
    };
    let selection = match &opts.selection {
        Some(s) => Some(select(&opts.dataset, s)?),
        None => None,
    };
    let to = match opts.format {
        ExportFormat::Layout(to) => to,
        ExportFormat::WebDataset => {
            let s = stereo_io::export_webdataset_selected(
                &opts.dataset,
                &opts.out,
                opts.from,
                &read,
                &opts.shards,
                selection.as_ref(),
            )?;
            super::card::write_card(&opts.out)?;
            return Ok(ExportSummary::Shards(s));
        }
    };
    let options = stereo_io::ExportOptions {
        from: opts.from,
        to,
        images,
        read,
    };
    let written =
        stereo_io::export_selected(&opts.dataset, &opts.out, &options, selection.as_ref())?;
    Ok(ExportSummary::Layout {
        format: to,
        written,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_formats_parse() {
        assert_eq!(parse_bytes("1GiB"), Ok(1 << 30));
        assert_eq!(parse_bytes("500MB"), Ok(500_000_000));
        assert_eq!(parse_bytes("1.5 KiB"), Ok(1536));
        assert_eq!(parse_bytes("4096"), Ok(4096));
        for bad in ["", "GiB", "1 parsec", "0", "-1MB"] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
        assert_eq!("webdataset".parse(), Ok(ExportFormat::WebDataset));
        assert_eq!(
            "kitti".parse(),
            Ok(ExportFormat::Layout(WritableFormat::Kitti2015))
        );
        let e = "tfrecord".parse::<ExportFormat>().unwrap_err();
        assert!(e.contains("webdataset"), "{e}");
    }

    #[test]
    fn webdataset_args_round_trip_through_their_command_line() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cmd {
            #[command(flatten)]
            shards: WebDatasetArgs,
        }
        let parse = |args: &[String]| {
            Cmd::try_parse_from(std::iter::once("x".to_string()).chain(args.iter().cloned()))
                .unwrap()
                .shards
        };
        let defaults = parse(&[]);
        assert_eq!(defaults, WebDatasetArgs::default());
        assert!(defaults.is_default());
        let given = WebDatasetArgs {
            shard_size: 3_000_000,
            shuffle_seed: 7,
            splits: "train=0.98,val=0.02".parse().unwrap(),
            selection: Some("occluded < 0.2 and category != 'tree'".parse().unwrap()),
        };
        assert!(!given.is_default());
        assert_eq!(parse(&given.to_args()), given);
        assert_eq!(given.options(true).splits, given.splits.0);
    }
}
