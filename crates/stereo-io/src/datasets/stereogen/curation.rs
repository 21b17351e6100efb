//! Self-curation records: which samples `stereogen curate` replaced, by what, under which rule.
//!
//! ```text
//! <root>/curation.jsonl                 one line per replaced sample ([`CurationRecord`])
//! <root>/curation/round-0001/           the round's replacements: a dataset of its own
//! ```
//!
//! `dataset.json` lists the rounds ([`CurationRound`]); the manifest holds the replacements
//! (their paths point into the round's folder) and no longer the samples they replaced, whose
//! files stay where they were for the record.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::sidecar::{SIDECAR_RECORD_VERSION, SidecarRecord};

/// `curation.jsonl`: every replaced sample of every round.
pub const CURATION_FILE: &str = "curation.jsonl";
/// The folder of `<root>` that holds each round's replacements.
pub const CURATION_DIR: &str = "curation";

/// The folder of round `round`'s replacements, relative to the dataset's root.
pub fn curation_round_dir(round: u32) -> PathBuf {
    PathBuf::from(CURATION_DIR).join(format!("round-{round:04}"))
}

/// One round of curation, as `dataset.json` records it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CurationRound {
    /// 1 for the first round.
    pub round: u32,
    /// The rule that flagged a sample, e.g. `all.bad_2 > 60`.
    pub rule: String,
    /// The scores file the round read, as given, and the SHA-256 of its bytes.
    pub scores: String,
    pub scores_sha256: String,
    /// The model that made the scores: its weights as the scores file names them, and their
    /// fingerprint (CRC-32C).
    pub model: String,
    pub model_fingerprint: String,
    /// Samples flagged (and replaced) in this round.
    pub replaced: u64,
    /// Samples of the dataset the scores covered.
    pub scored: u64,
    /// Where the replacements were rendered, relative to the root ([`curation_round_dir`]).
    pub dir: PathBuf,
    /// The manifest holds the round's replacements; `false` while they are being rendered.
    pub complete: bool,
}

/// One line of `curation.jsonl`: a sample flagged in a round and the sample that replaced it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CurationRecord {
    #[serde(default = "first_version")]
    pub version: u32,
    pub round: u32,
    /// The flagged sample.
    pub index: u64,
    pub id: String,
    pub category: String,
    /// Its score under the round's rule.
    pub score: f64,
    /// The replacement: a fresh index drawn from (seed, `index`, `round`), of the same category.
    pub replacement_index: u64,
    pub replacement_id: String,
}

fn first_version() -> u32 {
    1
}

impl CurationRecord {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        round: u32,
        index: u64,
        id: impl Into<String>,
        category: impl Into<String>,
        score: f64,
        replacement_index: u64,
        replacement_id: impl Into<String>,
    ) -> Self {
        Self {
            version: SIDECAR_RECORD_VERSION,
            round,
            index,
            id: id.into(),
            category: category.into(),
            score,
            replacement_index,
            replacement_id: replacement_id.into(),
        }
    }
}

impl SidecarRecord for CurationRecord {
    const WHAT: &'static str = "curation record";
}
