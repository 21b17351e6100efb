//! The network's weights and how inference runs it: one set of flags for every command that runs
//! or exports inference (`infer`, `eval`, `score`, `export onnx`), whose ranges and defaults come
//! from [`InferenceOptions`].

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::builder::RangedU64ValueParser;
use crestereo::InferenceOptions;

#[derive(Debug, Clone, clap::Args)]
pub struct NetworkArgs {
    /// Weights: a reference PyTorch state dict (.pt/.pth), a Burn record (.mpk), a checkpoint
    /// directory or a training run (its newest checkpoint).
    #[arg(long, env = "CRESTEREO_WEIGHTS")]
    pub weights: Option<PathBuf>,
    /// Refinement iterations per pass.
    #[arg(long, default_value_t = InferenceOptions::default().iters, value_parser = RangedU64ValueParser::<usize>::new().range(1..))]
    pub iters: usize,
    /// Stacked cascades, 1 to 4: 1 is one full-resolution pass; 2 the reference test procedure
    /// (half resolution, then full resolution from that); each more starts at half the size.
    #[arg(long, default_value_t = InferenceOptions::default().stages, value_parser = stages())]
    pub stages: usize,
}

/// `--stages`' range, [`InferenceOptions::STAGES`].
fn stages() -> RangedU64ValueParser<usize> {
    let range = InferenceOptions::STAGES;
    RangedU64ValueParser::new().range(*range.start() as u64..=*range.end() as u64)
}

impl NetworkArgs {
    pub fn options(&self) -> InferenceOptions {
        InferenceOptions {
            iters: self.iters,
            stages: self.stages,
        }
    }

    /// `--weights`, or one line saying it is missing.
    pub fn weights(&self) -> Result<&Path> {
        required_weights(self.weights.as_deref())
    }
}

/// A command's `--weights`, or one line saying it is missing.
pub fn required_weights(weights: Option<&Path>) -> Result<&Path> {
    weights.context("no weights given: pass --weights FILE or set CRESTEREO_WEIGHTS")
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        network: NetworkArgs,
    }

    #[test]
    fn the_ranges_are_the_library_rule() {
        let parse =
            |args: &[&str]| Cli::try_parse_from(std::iter::once("t").chain(args.iter().copied()));
        let n = parse(&[]).unwrap().network;
        assert_eq!((n.iters, n.stages), (20, 2));
        for stages in InferenceOptions::STAGES {
            let n = parse(&["--stages", &stages.to_string()]).unwrap().network;
            assert_eq!(n.options().stages, stages);
            n.options().check().unwrap();
        }
        for bad in ["0", "5"] {
            let e = parse(&["--stages", bad]).err().unwrap().to_string();
            assert!(e.contains("1..=4"), "{e}");
        }
        assert!(parse(&["--iters", "0"]).is_err());
    }
}
