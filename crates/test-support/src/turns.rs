//! What a machine holds once, taken in turn by the tests of one process: apt-get's package
//! database, the local Slurm cluster's node and the Python module's cargo folder. The end-to-end tests are one binary whose tests
//! run side by side, so a Chromium install may meet a Slurm install, and two clusters would both
//! name this machine's one node.

use std::sync::{Mutex, MutexGuard};

static APT: Mutex<()> = Mutex::new(());
static SLURM_NODE: Mutex<()> = Mutex::new(());
static PYTHON_EXT: Mutex<()> = Mutex::new(());

/// A test that failed while holding a turn leaves nothing half-done that the next one needs
/// (apt-get and the cluster script clean up after themselves), so a poisoned lock is taken as is.
fn take(lock: &'static Mutex<()>) -> MutexGuard<'static, ()> {
    lock.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Held while apt-get runs (dpkg's own lock makes a second apt-get fail, not wait).
pub fn apt() -> MutexGuard<'static, ()> {
    take(&APT)
}

/// Held from a local Slurm cluster's start to its stop.
pub fn slurm_node() -> MutexGuard<'static, ()> {
    take(&SLURM_NODE)
}

/// Held while maturin builds the Python module into `<target>/python-ext`, the one cargo folder
/// every such build shares (the README's wheel block, the wheel tests, the module the Python
/// checks import), so each compiles only what changed. Cargo's own lock would serialise the
/// compiles but not maturin's copy of the library that one build made and the next overwrites.
pub fn python_ext() -> MutexGuard<'static, ()> {
    take(&PYTHON_EXT)
}
