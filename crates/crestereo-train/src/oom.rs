//! Device work that may run out of memory, turned into one clear error. The GPU backends panic
//! when an allocation fails (CubeCL's memory management has no error path to the caller); the
//! panic is caught here, its report kept off the terminal, and the user told what ran out and
//! what to lower.
//!
//! CubeCL runs a device's work on a thread of its own, and that is where a failed allocation
//! panics (wgpu: "can't allocate buffer of size …"). The caller then sees only what follows:
//! on lavapipe with the process's memory limited, thousands of follow-on panics ("Ordering is
//! bigger than operations", "CallError") and an abort (SIGABRT). So a memory panic on *any*
//! thread while [`on_device`] work runs ends the process at once, with the same one line and
//! [`EXIT_OUT_OF_MEMORY`]. Files are written whole or not at all (temp name, rename), so the
//! last whole checkpoint stays.

use std::cell::RefCell;
use std::panic::AssertUnwindSafe;
use std::sync::{Mutex, Once};

use anyhow::{Result, anyhow};

thread_local! {
    /// While set, panics on this thread are recorded here instead of printed.
    static CAUGHT: RefCell<Option<Option<String>>> = const { RefCell::new(None) };
}

/// The exit status of a process stopped because a device thread ran out of memory: 71
/// (sysexits.h's EX_OSERR, a system resource failed), apart from 1 so that a job script can tell
/// it from other errors.
pub const EXIT_OUT_OF_MEMORY: u8 = 71;

/// The [`on_device`] work running in the process (what, what to lower), newest last, with the
/// id that removes it.
static ACTIVE: Mutex<Vec<(u64, String, String)>> = Mutex::new(Vec::new());

fn oom_error(what: &str, advice: &str, message: &str) -> String {
    let said = message.lines().next().unwrap_or("");
    // CubeCL's wgpu server unwraps the allocation's error: keep the error, not the unwrap.
    let said = said
        .strip_prefix("called `Result::unwrap()` on an `Err` value: ")
        .unwrap_or(said);
    format!("the device ran out of memory during {what}: {advice} (the backend said: {said})")
}

fn install_hook() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let message = info
                .payload()
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| info.payload().downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic".into());
            let caught = CAUGHT.with(|c| {
                let mut c = c.borrow_mut();
                match c.as_mut() {
                    Some(slot) => {
                        *slot = Some(message.clone());
                        true
                    }
                    None => false,
                }
            });
            if !caught {
                if is_out_of_memory(&message) {
                    let active = ACTIVE
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .last()
                        .cloned();
                    if let Some((_, what, advice)) = active {
                        eprintln!("error: {}", oom_error(&what, &advice, &message));
                        std::process::exit(i32::from(EXIT_OUT_OF_MEMORY));
                    }
                }
                default(info);
            }
        }));
    });
}

/// What to lower when a training step does not fit.
pub const TRAINING_ADVICE: &str = "lower --batch-size (or spread it over more replicas, or keep it with --accumulate), --crop or --iters";

/// Whether a panic message speaks of exhausted memory (CubeCL, wgpu and CUDA spell it
/// differently).
pub fn is_out_of_memory(message: &str) -> bool {
    let m = message.to_ascii_lowercase();
    [
        "out of memory",
        "outofmemory",
        "out_of_memory",
        "not enough memory",
        "memory allocation",
        "allocation failed",
        "failed to allocate",
        "can't allocate",
    ]
    .iter()
    .any(|k| m.contains(k))
}

/// Runs `work` (device work described by `what`); a panic that says the device ran out of
/// memory becomes "ran out of memory during WHAT: ADVICE", any other panic an error with its
/// message.
pub fn on_device<T>(work: impl FnOnce() -> Result<T>, what: &str, advice: &str) -> Result<T> {
    install_hook();
    struct Active(u64);
    impl Drop for Active {
        fn drop(&mut self) {
            let mut a = ACTIVE.lock().unwrap_or_else(|e| e.into_inner());
            a.retain(|(id, ..)| *id != self.0);
        }
    }
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let id = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    ACTIVE
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .push((id, what.to_owned(), advice.to_owned()));
    let _active = Active(id);
    CAUGHT.with(|c| *c.borrow_mut() = Some(None));
    let result = std::panic::catch_unwind(AssertUnwindSafe(work));
    let message = CAUGHT.with(|c| c.borrow_mut().take()).flatten();
    match result {
        Ok(r) => r,
        Err(_) => {
            let message = message.unwrap_or_else(|| "a panic".into());
            if is_out_of_memory(&message) {
                Err(anyhow!(oom_error(what, advice, &message)))
            } else {
                Err(anyhow!("{what} failed: {message}"))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_memory_panic_becomes_the_advice_and_others_their_message() {
        let e = on_device::<()>(
            || panic!("Out of memory: could not allocate 4 GiB"),
            "a training step",
            "lower --batch-size",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with(
                "the device ran out of memory during a training step: lower --batch-size"
            ),
            "{e}"
        );
        let e = on_device::<()>(|| panic!("index 3 out of range"), "inference", "-")
            .unwrap_err()
            .to_string();
        assert_eq!(e, "inference failed: index 3 out of range");
        assert_eq!(on_device(|| Ok(5), "x", "y").unwrap(), 5);
    }
}
