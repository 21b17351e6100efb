//! `stereogen report`: one self-contained HTML page about a dataset.

use std::path::PathBuf;

/// One self-contained HTML file about DATASET.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// Dataset directory.
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,
}

pub fn run(_args: ReportArgs) -> anyhow::Result<()> {
    anyhow::bail!("not yet")
}
