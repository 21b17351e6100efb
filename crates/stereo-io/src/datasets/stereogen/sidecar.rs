//! The sidecar logs beside the manifest: `failures.jsonl` (samples that failed, with the reason)
//! and `skipped_assets.jsonl` (asset files that could not be used, with the reason). One JSON
//! line per record, read with the manifest's rule for an unfinished last line
//! ([`super::json_lines`]).
//!
//! Each record carries the `version` of its layout; a line without one is version 1 (the layout
//! of the lines written before records were versioned), a newer version is an error naming the
//! file and line. Both logs are small and written by the dataset's lock holder only: each change
//! rewrites the whole file atomically, so a kill never leaves half a line.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::json_lines::read_finished_lines;
use crate::error::{Error, Result};

/// The layout version of the records this code writes and reads.
pub const SIDECAR_RECORD_VERSION: u32 = 1;

fn first_version() -> u32 {
    1
}

/// One line of `failures.jsonl`: a sample that failed and is not in the manifest.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FailureRecord {
    #[serde(default = "first_version")]
    pub version: u32,
    /// The sample's index.
    pub index: u64,
    pub error: String,
    /// The worker's Python traceback, when it sent one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub traceback: Option<String>,
}

impl FailureRecord {
    pub fn new(index: u64, error: impl Into<String>, traceback: Option<String>) -> Self {
        Self {
            version: SIDECAR_RECORD_VERSION,
            index,
            error: error.into(),
            traceback,
        }
    }
}

/// One line of `skipped_assets.jsonl`: an asset file that could not be used.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SkippedAssetRecord {
    #[serde(default = "first_version")]
    pub version: u32,
    pub path: PathBuf,
    pub reason: String,
    /// The sample whose worker refused it; `None` when the asset index refused it up front.
    #[serde(default)]
    pub sample: Option<u64>,
}

impl SkippedAssetRecord {
    pub fn new(path: impl Into<PathBuf>, reason: impl Into<String>, sample: Option<u64>) -> Self {
        Self {
            version: SIDECAR_RECORD_VERSION,
            path: path.into(),
            reason: reason.into(),
            sample,
        }
    }
}

/// A record type of one sidecar log.
pub trait SidecarRecord: Serialize + DeserializeOwned {
    /// What one line is, for error messages ("failure record").
    const WHAT: &'static str;
}

impl SidecarRecord for FailureRecord {
    const WHAT: &'static str = "failure record";
}

impl SidecarRecord for SkippedAssetRecord {
    const WHAT: &'static str = "skipped-asset record";
}

/// The finished records of a sidecar log, and what was left out.
#[derive(Debug, Clone, PartialEq)]
pub struct SidecarContents<R> {
    pub records: Vec<R>,
    /// Bytes of an unfinished last line that was left out; 0 when none.
    pub unfinished_bytes: u64,
}

/// Just the version of a line, read before the record so a newer layout is named as such
/// rather than as whatever field it lacks.
#[derive(Deserialize)]
struct VersionOnly {
    #[serde(default = "first_version")]
    version: u32,
}

fn parse_record<R: SidecarRecord>(path: &Path, number: usize, text: &str) -> Result<R> {
    let bad = |e: serde_json::Error| {
        Error::format(path, format!("line {number} is not a {}: {e}", R::WHAT))
    };
    let version = serde_json::from_str::<VersionOnly>(text)
        .map_err(bad)?
        .version;
    if version != SIDECAR_RECORD_VERSION {
        return Err(Error::format(
            path,
            format!(
                "line {number} is a version {version} {}; this stereogen reads version {SIDECAR_RECORD_VERSION}",
                R::WHAT
            ),
        ));
    }
    serde_json::from_str(text).map_err(bad)
}

/// The finished lines of the log at `path` with their records; a missing file has none.
fn read_lines<R: SidecarRecord>(path: &Path) -> Result<(Vec<(String, R)>, u64)> {
    let file = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((Vec::new(), 0)),
        Err(e) => return Err(Error::io(path, e)),
    };
    read_lines_from(BufReader::new(file), path)
}

fn read_lines_from<R: SidecarRecord>(
    reader: impl BufRead,
    path: &Path,
) -> Result<(Vec<(String, R)>, u64)> {
    let mut lines = Vec::new();
    let unfinished = read_finished_lines(reader, path, |number, text| {
        lines.push((text.to_string(), parse_record(path, number, text)?));
        Ok(())
    })?;
    Ok((lines, unfinished))
}

/// Replaces the log with `lines` (removes it when there are none), atomically.
fn rewrite(path: &Path, lines: impl Iterator<Item = String>) -> Result<()> {
    let text: String = lines.map(|l| l + "\n").collect();
    if text.is_empty() {
        crate::atomic::remove_file_durably(path)
    } else {
        crate::atomic::write_bytes_atomically(path, text.as_bytes())
    }
}

/// Reads the finished records of a sidecar log (see the module docs for the rules).
pub fn read_sidecar<R: SidecarRecord>(path: &Path) -> Result<SidecarContents<R>> {
    let (lines, unfinished_bytes) = read_lines(path)?;
    Ok(SidecarContents::of_lines(lines, unfinished_bytes))
}

/// [`read_sidecar`] of the bytes of `reader` (`path` names them in errors).
pub fn read_sidecar_from<R: SidecarRecord>(
    reader: impl BufRead,
    path: &Path,
) -> Result<SidecarContents<R>> {
    let (lines, unfinished_bytes) = read_lines_from(reader, path)?;
    Ok(SidecarContents::of_lines(lines, unfinished_bytes))
}

impl<R> SidecarContents<R> {
    fn of_lines(lines: Vec<(String, R)>, unfinished_bytes: u64) -> Self {
        Self {
            records: lines.into_iter().map(|(_, r)| r).collect(),
            unfinished_bytes,
        }
    }
}

/// Appends `records` to a sidecar log (an unfinished last line is dropped); the caller holds the
/// dataset's lock.
pub fn append_sidecar<R: SidecarRecord>(path: &Path, records: &[R]) -> Result<()> {
    if records.is_empty() {
        return Ok(());
    }
    let (old, _) = read_lines::<R>(path)?;
    let mut new = Vec::with_capacity(records.len());
    for r in records {
        let line = serde_json::to_string(r)
            .map_err(|e| Error::format(path, format!("cannot encode a {}: {e}", R::WHAT)))?;
        new.push(line);
    }
    rewrite(path, old.into_iter().map(|(text, _)| text).chain(new))
}

/// Keeps only the records of a sidecar log for which `keep` holds (each kept line as it was
/// written); returns how many were dropped. The caller holds the dataset's lock.
pub fn retain_sidecar<R: SidecarRecord>(path: &Path, keep: impl Fn(&R) -> bool) -> Result<usize> {
    let (lines, unfinished) = read_lines::<R>(path)?;
    let before = lines.len();
    let kept: Vec<String> = lines
        .into_iter()
        .filter(|(_, r)| keep(r))
        .map(|(text, _)| text)
        .collect();
    let dropped = before - kept.len();
    if dropped > 0 || unfinished > 0 {
        rewrite(path, kept.into_iter())?;
    }
    Ok(dropped)
}

/// Reads `failures.jsonl`.
pub fn read_failures(path: &Path) -> Result<SidecarContents<FailureRecord>> {
    read_sidecar(path)
}

/// Reads `skipped_assets.jsonl`.
pub fn read_skipped_assets(path: &Path) -> Result<SidecarContents<SkippedAssetRecord>> {
    read_sidecar(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn failure(index: u64) -> FailureRecord {
        FailureRecord::new(
            index,
            format!("sample {index} raised"),
            Some("Traceback…".into()),
        )
    }

    fn skipped(name: &str) -> SkippedAssetRecord {
        SkippedAssetRecord::new(format!("/meshes/{name}"), "no vertices", Some(4))
    }

    #[test]
    fn records_round_trip_through_append_and_read() {
        let dir = tempfile::tempdir().unwrap();
        let failures = dir.path().join("failures.jsonl");
        append_sidecar(&failures, &[failure(0), failure(3)]).unwrap();
        append_sidecar(&failures, &[FailureRecord::new(9, "hung", None)]).unwrap();
        let read = read_failures(&failures).unwrap();
        assert_eq!(
            read.records,
            vec![failure(0), failure(3), FailureRecord::new(9, "hung", None)]
        );
        assert_eq!(read.unfinished_bytes, 0);

        let assets = dir.path().join("skipped_assets.jsonl");
        append_sidecar(
            &assets,
            &[
                skipped("a.obj"),
                SkippedAssetRecord::new("/b.obj", "NaN", None),
            ],
        )
        .unwrap();
        assert_eq!(
            read_skipped_assets(&assets).unwrap().records,
            vec![
                skipped("a.obj"),
                SkippedAssetRecord::new("/b.obj", "NaN", None)
            ]
        );
        assert!(
            read_failures(&dir.path().join("none.jsonl"))
                .unwrap()
                .records
                .is_empty()
        );
    }

    #[test]
    fn lines_from_before_versions_read_as_version_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("failures.jsonl");
        std::fs::write(&path, "{\"index\":5,\"error\":\"boom\"}\n").unwrap();
        assert_eq!(
            read_failures(&path).unwrap().records,
            vec![FailureRecord::new(5, "boom", None)]
        );
    }

    #[test]
    fn an_unfinished_last_line_is_left_out_then_cut_by_the_next_write() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("failures.jsonl");
        let whole = serde_json::to_string(&failure(1)).unwrap();
        for tail in [&whole[..whole.len() / 2], whole.as_str()] {
            let first = serde_json::to_string(&failure(0)).unwrap() + "\n";
            std::fs::write(&path, first.clone() + tail).unwrap();
            let c = read_failures(&path).unwrap();
            assert_eq!(
                (c.records, c.unfinished_bytes),
                (vec![failure(0)], tail.len() as u64)
            );
            append_sidecar(&path, &[failure(2)]).unwrap();
            let text = std::fs::read_to_string(&path).unwrap();
            assert_eq!(
                text,
                first + &serde_json::to_string(&failure(2)).unwrap() + "\n"
            );
        }
    }

    #[test]
    fn retain_drops_records_and_removes_an_emptied_log() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("failures.jsonl");
        append_sidecar(&path, &[failure(0), failure(1), failure(2)]).unwrap();
        assert_eq!(
            retain_sidecar(&path, |r: &FailureRecord| r.index != 1).unwrap(),
            1
        );
        assert_eq!(
            read_failures(&path).unwrap().records,
            vec![failure(0), failure(2)]
        );
        assert_eq!(retain_sidecar(&path, |_: &FailureRecord| false).unwrap(), 2);
        assert!(!path.exists());
    }

    #[test]
    fn a_newer_version_or_a_bad_record_names_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("skipped_assets.jsonl");
        let good = serde_json::to_string(&skipped("a.obj")).unwrap() + "\n";
        let cases = [
            (
                "{\"version\":2,\"path\":\"/x.obj\",\"reason\":\"r\"}\n",
                "version 2 skipped-asset record; this stereogen reads version 1",
            ),
            (
                "{\"path\":\"/x.obj\"}\n",
                "not a skipped-asset record: missing field `reason`",
            ),
            (
                "{\"path\":\"/x.obj\",\"reason\":7}\n",
                "not a skipped-asset record: invalid type",
            ),
            ("not json\n", "not a skipped-asset record"),
        ];
        for (bad, says) in cases {
            std::fs::write(&path, good.clone() + bad).unwrap();
            let e = read_skipped_assets(&path).unwrap_err().to_string();
            assert!(
                e.contains("skipped_assets.jsonl") && e.contains("line 2 is") && e.contains(says),
                "{e}"
            );
            let e = append_sidecar(&path, &[skipped("b.obj")])
                .unwrap_err()
                .to_string();
            assert!(e.contains("line 2"), "a write over a bad log refuses: {e}");
        }
    }
}
