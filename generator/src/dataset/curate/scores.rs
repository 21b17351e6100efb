//! Reading `crestereo score`'s output: the one interface between the trainer and the generator
//! (the generator never links the network). The file is JSON lines: a header (`"scores":
//! "crestereo-scores"`, the weights and their CRC-32C), then one line per sample with its id and
//! the per-image metrics of `crestereo eval` on all valid (`all`) and non-occluded (`nonocc`)
//! pixels, or an `error` where the sample could not be scored.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use anyhow::{Context, bail};
use serde_json::Value;
use stereo_io::digest::sha256_hex;

/// Which pixels a rule reads: the scores file's `all` or `nonocc` metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Pixels {
    /// Every pixel with a valid ground truth (FoundationStereo's BP-2 rule).
    All,
    /// The non-occluded ones (left-right check of the two ground-truth maps).
    Nonocc,
}

impl Pixels {
    fn key(self) -> &'static str {
        match self {
            Self::All => "all",
            Self::Nonocc => "nonocc",
        }
    }
}

/// A sample is flagged when its Bad-2 (percentage of pixels more than 2 px off) on `pixels`
/// exceeds `max_bad2`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlagRule {
    pub max_bad2: f64,
    pub pixels: Pixels,
}

impl FlagRule {
    /// FoundationStereo's rule for its FSD data: BP-2 above 60%.
    pub const DEFAULT_MAX_BAD2: f64 = 60.0;

    /// The score this rule compares, from one sample's line (`None`: no metrics on those pixels).
    fn score(&self, line: &Value) -> Option<f64> {
        line.get(self.pixels.key())?.get("bad_2")?.as_f64()
    }

    pub fn flags(&self, score: f64) -> bool {
        score > self.max_bad2
    }
}

impl fmt::Display for FlagRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.bad_2 > {}", self.pixels.key(), self.max_bad2)
    }
}

/// A scores file as read for one rule.
#[derive(Debug, Clone)]
pub struct Scores {
    /// The weights the header names, and their fingerprint.
    pub model: String,
    pub model_fingerprint: String,
    /// SHA-256 of the file's bytes.
    pub sha256: String,
    /// Sample id → its score under the rule; `None` for a sample the scorer could not score or
    /// that has no metrics on the rule's pixels.
    pub by_id: BTreeMap<String, Option<f64>>,
}

/// The most bytes read of a scores file: about 1 KiB a sample, a few million samples.
const MAX_SCORES_BYTES: u64 = 8 << 30;

/// Reads `path` (see the module's doc) and scores every sample under `rule`.
pub fn read_scores(path: &Path, rule: &FlagRule) -> anyhow::Result<Scores> {
    let size = std::fs::metadata(path)
        .with_context(|| format!("cannot read the scores file {}", path.display()))?
        .len();
    if size > MAX_SCORES_BYTES {
        bail!(
            "{}: {size} bytes is more than a scores file of any dataset this tool makes ({MAX_SCORES_BYTES})",
            path.display()
        );
    }
    let bytes = std::fs::read(path)
        .with_context(|| format!("cannot read the scores file {}", path.display()))?;
    let sha256 = sha256_hex(&bytes);
    let text = std::str::from_utf8(&bytes)
        .with_context(|| format!("{} is not a scores file (not text)", path.display()))?;
    // Only whole lines: a scorer killed mid-append leaves an unfinished last one.
    let whole = text.rfind('\n').map_or("", |i| &text[..i]);
    let mut lines = whole.lines().enumerate();
    let header: Value = match lines.next() {
        Some((_, first)) => serde_json::from_str(first)
            .with_context(|| format!("{}: line 1 is not JSON", path.display()))?,
        None => bail!("{} is empty: no scores", path.display()),
    };
    if header.get("scores").and_then(Value::as_str) != Some("crestereo-scores") {
        bail!(
            "{} is not a scores file of `crestereo score` (its first line has no \"scores\": \"crestereo-scores\")",
            path.display()
        );
    }
    let text_of = |key: &str| {
        header
            .get(key)
            .and_then(Value::as_str)
            .unwrap_or("?")
            .to_string()
    };
    let mut by_id = BTreeMap::new();
    for (i, line) in lines {
        let v: Value = serde_json::from_str(line)
            .with_context(|| format!("{}: line {} is not JSON", path.display(), i + 1))?;
        let Some(id) = v.get("id").and_then(Value::as_str) else {
            bail!("{}: line {} names no sample (`id`)", path.display(), i + 1);
        };
        if by_id.insert(id.to_string(), rule.score(&v)).is_some() {
            bail!(
                "{}: sample {id} is scored twice (line {})",
                path.display(),
                i + 1
            );
        }
    }
    Ok(Scores {
        model: text_of("weights"),
        model_fingerprint: text_of("weights_crc32c"),
        sha256,
        by_id,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str) -> std::path::PathBuf {
        let p = dir.join("scores.jsonl");
        std::fs::write(&p, text).unwrap();
        p
    }

    const HEADER: &str = r#"{"scores":"crestereo-scores","dataset":"d","weights":"run/w.mpk","weights_crc32c":"0badf00d","iters":2,"stages":2,"lr_tolerance_px":1.0}"#;

    #[test]
    fn reads_the_rule_s_metric_per_sample_and_skips_a_torn_last_line() {
        let dir = tempfile::tempdir().unwrap();
        let text = format!(
            "{HEADER}\n{}\n{}\n{}\n{{\"id\":\"0000009\",\"al",
            r#"{"id":"0000001","all":{"bad_2":70.5},"nonocc":{"bad_2":10.0},"index":0}"#,
            r#"{"id":"0000002","all":{"bad_2":20.0},"nonocc":null,"index":1}"#,
            r#"{"index":2,"id":"0000003","error":"cannot read"}"#,
        );
        let path = write(dir.path(), &text);
        let all = FlagRule {
            max_bad2: 60.0,
            pixels: Pixels::All,
        };
        let s = read_scores(&path, &all).unwrap();
        assert_eq!(s.model, "run/w.mpk");
        assert_eq!(s.model_fingerprint, "0badf00d");
        assert_eq!(s.by_id.len(), 3);
        assert_eq!(s.by_id["0000001"], Some(70.5));
        assert_eq!(s.by_id["0000002"], Some(20.0));
        assert_eq!(s.by_id["0000003"], None);
        assert!(all.flags(70.5) && !all.flags(60.0));
        let nonocc = FlagRule {
            pixels: Pixels::Nonocc,
            ..all
        };
        let s = read_scores(&path, &nonocc).unwrap();
        assert_eq!(s.by_id["0000001"], Some(10.0));
        assert_eq!(s.by_id["0000002"], None);
        assert_eq!(nonocc.to_string(), "nonocc.bad_2 > 60");
    }

    #[test]
    fn refuses_files_that_are_not_scores() {
        let dir = tempfile::tempdir().unwrap();
        let rule = FlagRule {
            max_bad2: 60.0,
            pixels: Pixels::All,
        };
        let path = write(dir.path(), "{\"id\":\"x\"}\n");
        let e = read_scores(&path, &rule).unwrap_err().to_string();
        assert!(e.contains("not a scores file"), "{e}");
        let path = write(
            dir.path(),
            &format!("{HEADER}\n{{\"id\":\"a\"}}\n{{\"id\":\"a\"}}\n"),
        );
        let e = read_scores(&path, &rule).unwrap_err().to_string();
        assert!(e.contains("scored twice"), "{e}");
    }
}
