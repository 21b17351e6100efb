//! `stereogen generate`: the library's run with a progress bar and a one-line summary.

use std::time::Duration;

use anyhow::bail;
use indicatif::{ProgressBar, ProgressStyle};
use stereogen::dataset::generate::Progress;
use stereogen::dataset::{DatasetLayout, GenerateCommand, generate};
use stereogen::interrupt::{self, Interrupted};

/// Draws the library's progress reports (a hidden bar when `show` is false).
pub(super) fn progress_bar(show: bool) -> ProgressBar {
    let bar = if show {
        ProgressBar::new(0)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} samples · {per_sec} · ETA {eta} {msg}")
            .expect("static template"),
    );
    bar
}

pub(super) fn draw(bar: &ProgressBar, event: Progress<'_>) {
    match event {
        Progress::Started { total, done } => {
            bar.set_length(total);
            bar.set_position(done);
            bar.reset_eta();
            bar.enable_steady_tick(Duration::from_millis(250));
        }
        Progress::Rendered { .. } => bar.inc(1),
        Progress::Failed { id, error, .. } => {
            bar.println(format!("sample {id} failed: {error}"));
            bar.inc(1);
        }
    }
}

/// Runs `command` with SIGTERM/SIGINT handled: a signal stops the run cleanly and the error is
/// [`Interrupted`] (the caller's exit status [`interrupt::EXIT_INTERRUPTED`]).
pub fn run(command: &GenerateCommand) -> anyhow::Result<()> {
    let mut opts = command.options()?;
    opts.stop = interrupt::install()?;
    let bar = progress_bar(!command.no_progress);
    let outcome = generate(&opts, &|event| draw(&bar, event));
    bar.finish_and_clear();
    let s = outcome?;
    eprintln!(
        "stereogen: {} rendered, {} already done, {} failed, {} worker restart(s) in {:.1} s ({:.2} s per sample per worker) -> {}",
        s.rendered,
        s.skipped,
        s.failed.len(),
        s.worker_restarts,
        s.seconds,
        s.seconds_per_sample,
        opts.dataset_dir().display()
    );
    if s.interrupted {
        return Err(Interrupted::now().into());
    }
    if !s.failed.is_empty() {
        let failures = DatasetLayout::new(opts.dataset_dir()).failures();
        bail!(
            "{} sample(s) failed (listed in {}); re-run the same command to retry them",
            s.failed.len(),
            failures.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use clap::Parser;
    use stereogen::dataset::shard::{ShardArg, ShardId};
    use stereogen::dataset::{GenerateCommand, RecipeArgs, RuntimeArgs, TaskArgs};
    use stereogen::render::Device;

    use crate::cli::{Cli, Command};

    /// Every field set, none to its default, so a flag that `to_args` forgets or spells
    /// differently from the parser changes the value read back.
    fn every_field_set() -> GenerateCommand {
        GenerateCommand {
            out: PathBuf::from("/farm/out dir"),
            task: TaskArgs {
                recipe: RecipeArgs {
                    recipe: "/jobs/recipe.toml".into(),
                    shapenet: Some("/data/ShapeNetCore.v2".into()),
                    meshes: Some("/data/objaverse".into()),
                    textures: Some("/data/photos".into()),
                },
                count: 200_000,
                seed: 7,
                start: 1_000,
                workers: 4,
                runtime: RuntimeArgs {
                    blender: Some("/opt/blender/blender".into()),
                    device: Device::Gpu,
                    threads: Some(3),
                    timeout: 77,
                    retries: 5,
                },
            },
            shard: Some(ShardArg::Fixed(ShardId::new(3, 64).unwrap())),
            shards: Some(64),
            break_lock: true,
            no_progress: true,
            fault: Some(
                "crash@3,hang@5,crash-always@7,hang-always@8,raise@9"
                    .parse()
                    .unwrap(),
            ),
        }
    }

    fn parse(args: Vec<String>) -> GenerateCommand {
        let argv = std::iter::once("stereogen".to_string()).chain(args.clone());
        match Cli::try_parse_from(argv) {
            Ok(Cli {
                command: Command::Generate(c),
            }) => c,
            Ok(other) => panic!("{args:?} parsed as {other:?}"),
            Err(e) => panic!("{args:?} does not parse: {e}"),
        }
    }

    #[test]
    fn the_command_line_that_to_args_writes_parses_back_to_the_same_value() {
        let x = every_field_set();
        let defaults = parse(vec![
            "generate".into(),
            "--out".into(),
            "o".into(),
            "--count".into(),
            "1".into(),
        ]);
        // Field by field, so the message names what differs; then the whole value.
        let back = parse(x.to_args());
        assert_ne!(back.task.recipe, defaults.task.recipe);
        assert_ne!(back.task.runtime, defaults.task.runtime);
        assert_eq!(back.task, x.task);
        assert_eq!(
            back.fault.as_ref().map(ToString::to_string),
            x.fault.as_ref().map(ToString::to_string)
        );
        assert_eq!(back, x);
        // Each optional part left out also reads back as left out.
        let mut sparse = x.clone();
        sparse.task.recipe.shapenet = None;
        sparse.task.runtime.threads = None;
        sparse.task.runtime.blender = None;
        (sparse.shard, sparse.shards, sparse.fault) = (Some(ShardArg::Auto), None, None);
        sparse.break_lock = false;
        assert_eq!(parse(sparse.to_args()), sparse);
    }
}
