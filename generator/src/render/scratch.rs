//! Scratch folders for a worker's intermediate files (its PNGs and depth EXRs, before they are
//! converted into the dataset), owned and cleaned up.
//!
//! Each render gets a folder `stereogen-<pid>-<random>`, named after the process that owns it and
//! removed when the render is done, fails or is abandoned (also on SIGTERM/SIGINT, see
//! [`crate::interrupt`]). A process killed outright (SIGKILL, a crash, a power cut)
//! cannot clean up: the next run on the machine removes every scratch folder whose owner is no
//! longer running ([`remove_orphans`]). This assumes one PID namespace per scratch location
//! (containers that share a `/dev/shm` must set `STEREOGEN_SCRATCH` apart).
//!
//! Where the folders go ([`choose_base`]): `$STEREOGEN_SCRATCH` when set; else `/dev/shm` (RAM,
//! so renders never touch the disk until the finished files are written) when it has room for
//! the run's intermediates and the machine's available memory covers them plus
//! [`RAM_RESERVE_BYTES`] for Blender itself; else `<dataset>/.scratch/` on the dataset's own
//! filesystem, which a machine short of RAM can afford.

use std::path::{Path, PathBuf};

/// Overrides where scratch folders go.
pub const SCRATCH_ENV: &str = "STEREOGEN_SCRATCH";
/// Memory left to Blender and everything else when `/dev/shm` is considered.
pub const RAM_RESERVE_BYTES: u64 = 1 << 30;
/// The folder inside a dataset used when RAM is short.
pub const DATASET_SCRATCH_DIR: &str = ".scratch";

const PREFIX: &str = "stereogen-";

/// Upper bound of one render's intermediates: per view an 8-bit RGB PNG and an uncompressed
/// float32 RGBA+Z EXR (what Blender writes is smaller).
pub fn bytes_per_render(width: u32, height: u32) -> u64 {
    u64::from(width) * u64::from(height) * 2 * (3 + 5 * 4)
}

/// The scratch location of a run writing into `dataset` with `workers` renders in flight, each
/// needing up to `bytes_per_render` (see the module docs).
pub fn choose_base(dataset: Option<&Path>, workers: usize, bytes_per_render: u64) -> PathBuf {
    if let Some(dir) = std::env::var_os(SCRATCH_ENV).filter(|v| !v.is_empty()) {
        return PathBuf::from(dir);
    }
    // Twice the need: a retried render briefly overlaps the folder of the one it replaces.
    let need = bytes_per_render.saturating_mul(2 * workers.max(1) as u64);
    let shm = Path::new("/dev/shm");
    if shm_fits(shm, need) {
        return shm.to_path_buf();
    }
    match dataset {
        Some(root) => root.join(DATASET_SCRATCH_DIR),
        None => std::env::temp_dir(),
    }
}

/// Where scratch folders go without a dataset to fall back on.
pub fn default_base() -> PathBuf {
    choose_base(None, 1, bytes_per_render(1920, 1080))
}

fn shm_fits(shm: &Path, need: u64) -> bool {
    if !shm.is_dir() || tempfile::tempdir_in(shm).is_err() {
        return false;
    }
    let free = free_bytes(shm).unwrap_or(0);
    let memory = available_memory().unwrap_or(u64::MAX);
    free >= need && memory >= need.saturating_add(RAM_RESERVE_BYTES)
}

/// Bytes an unprivileged process can still write on the filesystem of `path`.
pub fn free_bytes(path: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some(st.f_bavail as u64 * st.f_frsize as u64)
}

/// `MemAvailable` of `/proc/meminfo`, in bytes.
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    Some(line.split_whitespace().nth(1)?.parse::<u64>().ok()? * 1024)
}

/// A fresh scratch folder in `base`, owned by this process; removed when dropped.
pub fn create(base: &Path) -> std::io::Result<tempfile::TempDir> {
    std::fs::create_dir_all(base)?;
    tempfile::Builder::new()
        .prefix(&format!("{PREFIX}{}-", std::process::id()))
        .tempdir_in(base)
}

/// The process a scratch folder's name says owns it.
fn owner(name: &str) -> Option<u32> {
    let (pid, rest) = name.strip_prefix(PREFIX)?.split_once('-')?;
    (!rest.is_empty()).then_some(())?;
    pid.parse().ok()
}

/// Whether process `pid` is running (signal 0 reaches it, or it exists under another user).
pub fn process_alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    if pid <= 0 {
        return false;
    }
    unsafe {
        libc::kill(pid, 0) == 0
            || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
    }
}

/// Every place this machine's runs may have put scratch folders: `$STEREOGEN_SCRATCH`,
/// `/dev/shm`, the system temp dir and, given one, the dataset's `.scratch`.
pub fn candidate_bases(dataset: Option<&Path>) -> Vec<PathBuf> {
    let mut bases: Vec<PathBuf> = std::env::var_os(SCRATCH_ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .into_iter()
        .collect();
    bases.extend([PathBuf::from("/dev/shm"), std::env::temp_dir()]);
    bases.extend(dataset.map(|d| d.join(DATASET_SCRATCH_DIR)));
    bases.dedup();
    bases
}

/// Removes the scratch folders in `bases` whose owning process is gone; returns how many. A
/// dataset's `.scratch` that is left empty is removed too.
pub fn remove_orphans(bases: &[PathBuf]) -> usize {
    let mut removed = 0;
    for base in bases {
        let Ok(entries) = std::fs::read_dir(base) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let orphan = owner(&name).is_some_and(|pid| !process_alive(pid));
            if orphan
                && e.file_type().is_ok_and(|t| t.is_dir())
                && std::fs::remove_dir_all(e.path()).is_ok()
            {
                removed += 1;
            }
        }
        if base.file_name().is_some_and(|n| n == DATASET_SCRATCH_DIR) {
            let _ = std::fs::remove_dir(base);
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folders_carry_their_owner_and_orphans_are_removed() {
        let base = tempfile::tempdir().unwrap();
        let mine = create(base.path()).unwrap();
        let name = mine
            .path()
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        assert_eq!(owner(&name), Some(std::process::id()));
        // A process that has exited: a child that is reaped.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let orphan = base.path().join(format!("stereogen-{dead}-abc123"));
        std::fs::create_dir(&orphan).unwrap();
        std::fs::write(orphan.join("left.png"), b"x").unwrap();
        let unrelated = base.path().join("stereogen-notes");
        std::fs::create_dir(&unrelated).unwrap();
        assert_eq!(remove_orphans(&[base.path().to_path_buf()]), 1);
        assert!(!orphan.exists() && mine.path().exists() && unrelated.exists());
        assert_eq!(
            owner("stereogen-XytK8w"),
            None,
            "names of older versions have no owner"
        );
    }

    #[test]
    fn an_explicit_location_wins_and_a_dataset_is_the_fallback() {
        let fallback = choose_base(Some(Path::new("/data/set")), 1, u64::MAX / 4);
        assert!(
            fallback == Path::new("/data/set/.scratch") || std::env::var_os(SCRATCH_ENV).is_some(),
            "{}",
            fallback.display()
        );
    }
}
