//! `manifest.jsonl`: one JSON line per finished sample, appended only after all its files are in
//! place. A line cut short by a kill is dropped (and truncated away) on the next open.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::layout::SamplePaths;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DisparitySummary {
    pub min: f32,
    pub max: f32,
    pub mean: f64,
    pub valid_fraction: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ManifestEntry {
    pub id: String,
    pub category: String,
    pub seed: u64,
    pub index: u64,
    pub files: SamplePaths,
    pub width: u32,
    pub height: u32,
    pub f_px: f64,
    pub baseline_m: f64,
    pub cx: f64,
    pub cy: f64,
    /// Statistics of the valid pixels of each view; `None` when a view has none.
    pub disparity_left: Option<DisparitySummary>,
    pub disparity_right: Option<DisparitySummary>,
    pub render_seconds: f64,
    /// Where the worker's time went: seconds per step (`build_s`, `colour_left_s`, `depth_left_s`, ...).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub render_timings: BTreeMap<String, f64>,
    /// What the worker did beyond the spec (which mesh candidate it used, objects it dropped).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
    /// SHA-256 of each file, keyed like `files`.
    pub sha256: BTreeMap<String, String>,
    pub stereogen_version: String,
}

/// An open manifest for appending.
pub struct Manifest {
    path: PathBuf,
    file: File,
}

impl Manifest {
    /// Reads all complete entries and opens the file for appending. A torn last line (a kill
    /// during the append) is cut off; any other malformed line is an error.
    pub fn open(path: &Path) -> anyhow::Result<(Self, Vec<ManifestEntry>)> {
        let mut file = OpenOptions::new().create(true).read(true).append(true).open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        let mut entries = Vec::new();
        let mut good_len = 0usize;
        let mut offset = 0usize;
        for line in text.split_inclusive('\n') {
            offset += line.len();
            let complete = line.ends_with('\n');
            let body = line.trim_end();
            if body.is_empty() {
                good_len = offset;
                continue;
            }
            match serde_json::from_str::<ManifestEntry>(body) {
                Ok(e) if complete => {
                    entries.push(e);
                    good_len = offset;
                }
                _ if !complete => break,
                Err(e) => anyhow::bail!("{}: line {} is not a manifest entry: {e}", path.display(), entries.len() + 1),
                Ok(_) => unreachable!(),
            }
        }
        if good_len < text.len() {
            tracing::warn!("{}: dropping a torn last line left by an interrupted run", path.display());
            file.set_len(good_len as u64)?;
            file.seek(SeekFrom::End(0))?;
        }
        Ok((Self { path: path.to_path_buf(), file }, entries))
    }

    /// Appends one entry and syncs it to disk.
    pub fn append(&mut self, entry: &ManifestEntry) -> anyhow::Result<()> {
        let mut line = serde_json::to_string(entry)?;
        line.push('\n');
        self.file.write_all(line.as_bytes()).with_context(|| format!("cannot append to {}", self.path.display()))?;
        self.file.sync_data().with_context(|| format!("cannot sync {}", self.path.display()))?;
        Ok(())
    }

    /// Reads the complete entries of a manifest without opening it for writing.
    pub fn read(path: &Path) -> anyhow::Result<Vec<ManifestEntry>> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        text.lines()
            .filter(|l| !l.trim().is_empty())
            .enumerate()
            .map(|(i, l)| serde_json::from_str(l).with_context(|| format!("{}: line {} is not a manifest entry", path.display(), i + 1)))
            .collect()
    }
}
