//! `stereogen generate`: the library's run with a progress bar and a one-line summary.

use std::time::Duration;

use anyhow::bail;
use indicatif::{ProgressBar, ProgressStyle};
use stereogen::dataset::generate::Progress;
use stereogen::dataset::interrupt::{self, Interrupted};
use stereogen::dataset::{DatasetLayout, GenerateOptions, generate};

/// Draws the library's progress reports (a hidden bar when `show` is false).
fn progress_bar(show: bool) -> ProgressBar {
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

fn draw(bar: &ProgressBar, event: Progress<'_>) {
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

/// Runs `opts` with SIGTERM/SIGINT handled: a signal stops the run cleanly and the error is
/// [`Interrupted`] (the caller's exit status [`interrupt::EXIT_INTERRUPTED`]).
pub fn run(opts: &GenerateOptions, show_progress: bool) -> anyhow::Result<()> {
    let mut opts = opts.clone();
    opts.stop = interrupt::install()?;
    let bar = progress_bar(show_progress);
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
