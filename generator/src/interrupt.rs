//! Stopping a run cleanly on SIGTERM or SIGINT (what a scheduler sends before it kills a task,
//! and what Ctrl-C sends).
//!
//! [`install`] registers handlers for both signals (once per process) and returns the process's
//! [`StopFlag`], which they set. A long-running command hands the flag to the library
//! ([`crate::dataset::generate::GenerateOptions::stop`]), which checks it between samples and while it waits for a
//! worker: `generate` then starts no new sample, kills the workers, abandons the samples they
//! were rendering (nothing of them reaches the dataset; they are rendered again on resume),
//! removes its scratch folders and returns; the CLI exits with [`EXIT_INTERRUPTED`]. A sample
//! whose files are being written when the signal arrives is finished first (that takes a
//! fraction of a second). Re-running the same command resumes.
//!
//! A second signal while the run is stopping ends the process at once, with the same exit
//! status; a scratch folder it leaves is removed by the next run on the machine.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// Exit status of a command stopped by SIGTERM or SIGINT: 75, `EX_TEMPFAIL` of `sysexits.h`
/// ("temporary failure; the user is invited to retry"). Distinct from 1 (an error) and from the
/// 128 + N a shell reports for a process killed by signal N.
pub const EXIT_INTERRUPTED: u8 = 75;

/// A flag that asks a run to stop; clones share it.
#[derive(Debug, Clone, Default)]
pub struct StopFlag(Arc<AtomicBool>);

impl StopFlag {
    /// A flag no signal sets (set it with [`StopFlag::set`]).
    pub fn new() -> Self {
        Self::default()
    }

    pub fn is_set(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }

    pub fn set(&self) {
        self.0.store(true, Ordering::SeqCst);
    }
}

/// The run stopped because a signal asked it to; the CLI maps it to [`EXIT_INTERRUPTED`].
#[derive(Debug, Clone, thiserror::Error)]
#[error("stopped by {signal}; nothing is half-written; re-run the same command to resume")]
pub struct Interrupted {
    /// `SIGTERM`, `SIGINT`, or `a stop request` when no signal was seen.
    pub signal: String,
}

impl Interrupted {
    /// Names the signal that set the process's flag, if one did.
    pub fn now() -> Self {
        Self {
            signal: received_signal().unwrap_or("a stop request").to_string(),
        }
    }
}

struct Handlers {
    flag: StopFlag,
    signal: Arc<AtomicUsize>,
}

static HANDLERS: OnceLock<Handlers> = OnceLock::new();

fn register() -> std::io::Result<Handlers> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    let handlers = Handlers {
        flag: StopFlag::new(),
        signal: Arc::new(AtomicUsize::new(0)),
    };
    for sig in [SIGTERM, SIGINT] {
        // Registered first, so it sees the flag as it was before this signal: set means a
        // second signal, which ends the process at once.
        flag::register_conditional_shutdown(
            sig,
            i32::from(EXIT_INTERRUPTED),
            Arc::clone(&handlers.flag.0),
        )?;
        flag::register_usize(sig, Arc::clone(&handlers.signal), sig as usize)?;
        flag::register(sig, Arc::clone(&handlers.flag.0))?;
    }
    Ok(handlers)
}

/// Installs the SIGTERM and SIGINT handlers (the first call does; later calls return the same
/// flag) and returns the flag they set.
pub fn install() -> std::io::Result<StopFlag> {
    if let Some(h) = HANDLERS.get() {
        return Ok(h.flag.clone());
    }
    let handlers = register()?;
    let flag = handlers.flag.clone();
    // Two threads racing here would both register; the loser's handlers then set a flag
    // nobody reads, which is harmless.
    let _ = HANDLERS.set(handlers);
    Ok(HANDLERS.get().map_or(flag, |h| h.flag.clone()))
}

/// The signal that set the installed flag: `SIGTERM` or `SIGINT`.
pub fn received_signal() -> Option<&'static str> {
    match HANDLERS.get()?.signal.load(Ordering::SeqCst) as i32 {
        signal_hook::consts::SIGTERM => Some("SIGTERM"),
        signal_hook::consts::SIGINT => Some("SIGINT"),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_signal_sets_the_flag_and_is_named() {
        let flag = install().unwrap();
        assert!(!flag.is_set());
        assert!(
            install().unwrap().0.as_ptr() == flag.0.as_ptr(),
            "one flag per process"
        );
        unsafe { libc::raise(libc::SIGTERM) };
        assert!(flag.is_set());
        assert_eq!(received_signal(), Some("SIGTERM"));
        assert!(
            Interrupted::now()
                .to_string()
                .contains("stopped by SIGTERM")
        );
    }
}
