//! Stopping a training run cleanly on SIGTERM or SIGINT, as a scheduler asks before it kills a
//! task (Slurm's `--signal=TERM@SECS`, preemption, `scancel`, Kubernetes' pod deletion).
//!
//! The first signal sets a flag; the run finishes the step it is in, writes a checkpoint and
//! exits with [`EXIT_INTERRUPTED`], which a job script takes as "requeue me" (`--resume`
//! continues exactly). In a data-parallel run the flag travels with the step's all-reduce, so
//! every replica stops after the same step even when only one was signalled. A second SIGINT
//! ends the process at once.

use std::sync::Arc;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

/// Exit status of a run stopped by SIGTERM/SIGINT after its checkpoint: 75, `EX_TEMPFAIL` of
/// `sysexits.h` (the generator's too).
pub const EXIT_INTERRUPTED: u8 = 75;

fn flag() -> &'static Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)))
}

/// Installs the handlers (once; later calls do nothing). Commands that train call it at start.
pub fn install() -> std::io::Result<()> {
    static INSTALLED: OnceLock<()> = OnceLock::new();
    if INSTALLED.get().is_some() {
        return Ok(());
    }
    use signal_hook::consts::{SIGINT, SIGTERM};
    // A second SIGINT (an impatient Ctrl-C) ends the process at once.
    signal_hook::flag::register_conditional_shutdown(SIGINT, 130, flag().clone())?;
    for sig in [SIGTERM, SIGINT] {
        signal_hook::flag::register(sig, flag().clone())?;
    }
    let _ = INSTALLED.set(());
    Ok(())
}

/// Whether a stop was asked for.
pub fn requested() -> bool {
    flag().load(Ordering::SeqCst)
}

/// Asks for a stop as a signal would (tests, and a rank that learns of another's signal).
pub fn request() {
    flag().store(true, Ordering::SeqCst);
}

/// The error a stopped run returns: the CLI exits with [`EXIT_INTERRUPTED`] on it.
#[derive(Debug)]
pub struct Interrupted {
    pub step: u64,
    pub checkpoint: Option<std::path::PathBuf>,
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "stopped by a signal after step {}", self.step)?;
        if let Some(c) = &self.checkpoint {
            write!(f, " with checkpoint {}", c.display())?;
        }
        write!(f, "; continue with --resume")
    }
}

impl std::error::Error for Interrupted {}
