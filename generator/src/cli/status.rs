//! `stereogen status OUT`: a farm's progress from its files.

use std::path::PathBuf;

use stereogen::dataset::status::{farm_status, status_lines};

#[derive(Debug, clap::Args)]
pub struct StatusArgs {
    /// A farm's shared output directory (or one dataset directory).
    #[arg(value_name = "OUT")]
    out: PathBuf,
}

pub fn run(a: StatusArgs) -> anyhow::Result<()> {
    for line in status_lines(&farm_status(&a.out)?) {
        println!("{line}");
    }
    Ok(())
}
