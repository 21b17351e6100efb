//! The one durable-write path of the project: a finished file appears whole under its final name
//! or not at all, and once the call returns it survives a power cut.
//!
//! Every write goes to a temporary name in the target's directory (same filesystem, so the
//! rename is atomic), every write call and the final flush are checked, the file is `fsync`ed,
//! renamed into place, and the directory is `fsync`ed so the rename itself is durable. On any
//! error the temporary file is removed and the error names the final path and the OS error, once.
//! Encoders therefore produce bytes in memory ([`write_bytes_atomically`]); an encoder that can
//! only write to a path goes through [`write_atomically`].
//!
//! A [`Batch`] holds the renames back until every file of a group is written (an exported sample
//! is all-or-nothing): see there.

use std::cell::RefCell;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};

/// Marks the temporary names of [`temp_sibling`].
const TEMP_MARK: &str = ".partial-";

/// A hidden temporary name in the same directory: `.NAME.partial-PID-N` (`N` counts this
/// process's temporary files, so two threads writing one target never share a temp file).
pub fn temp_sibling(path: &Path) -> PathBuf {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}{TEMP_MARK}{}-{n}", std::process::id()))
}

/// Whether a file name is one of [`temp_sibling`]'s (left behind if a process died mid-write).
pub fn is_temp_name(name: &str) -> bool {
    name.starts_with('.') && name.contains(TEMP_MARK)
}

/// The process that owns a temporary name of [`temp_sibling`], if the name says (names of older
/// versions end in the bare pid).
pub fn temp_owner(name: &str) -> Option<u32> {
    let tail = &name[name.rfind(TEMP_MARK)? + TEMP_MARK.len()..];
    tail.split('-').next()?.parse().ok()
}

/// Whether process `pid` may still be running. Only Linux is asked (`/proc`); elsewhere every
/// owner counts as alive, so nothing of a running process is ever removed.
pub fn process_alive(pid: u32) -> bool {
    if cfg!(target_os = "linux") && Path::new("/proc/self").exists() {
        Path::new("/proc").join(pid.to_string()).exists()
    } else {
        true
    }
}

/// Removes the temporary files of dead processes ([`temp_sibling`], [`temp_owner`]) under `root`,
/// recursively; returns how many. Names without an owner are left alone.
pub fn remove_orphaned_temp_files(root: &Path) -> usize {
    walkdir::WalkDir::new(root)
        .into_iter()
        .flatten()
        .filter(|e| e.file_type().is_file() || e.file_type().is_symlink())
        .filter(|e| {
            let name = e.file_name().to_string_lossy();
            is_temp_name(&name) && temp_owner(&name).is_some_and(|pid| !process_alive(pid))
        })
        .filter(|e| fs::remove_file(e.path()).is_ok())
        .count()
}

/// Writes `bytes` to `path` durably (see the module docs).
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_sibling(path);
    let written = (|| {
        let mut file = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()
    })();
    let outcome = written
        .map_err(|e| Error::io(path, e))
        .and_then(|()| place(&tmp, path));
    if outcome.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    outcome
}

/// Calls `write` with a temporary path beside `path`, then makes it durable and renames it into
/// place. On any error the temporary file is removed and `path` is left untouched.
///
/// `write` must check every write and its final flush: an encoder that writes through a
/// `BufWriter` and lets it drop loses the error of the last flush (a disk that filled up), and
/// the short file would be renamed into place. Prefer [`write_bytes_atomically`].
pub fn write_atomically<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&Path) -> Result<()>,
{
    let tmp = temp_sibling(path);
    let outcome = write(&tmp).and_then(|()| {
        let file = fs::File::open(&tmp).map_err(|e| Error::io(path, e))?;
        file.sync_all().map_err(|e| Error::io(path, e))?;
        place(&tmp, path)
    });
    if outcome.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    outcome
}

/// Makes the finished temporary file `tmp` visible as `path`: now, or at the commit of the
/// thread's open [`Batch`]. A rename onto another temporary name (an encoder writing through a
/// nested atomic write) is never held back.
pub(crate) fn place(tmp: &Path, path: &Path) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if !is_temp_name(&name)
        && BATCH
            .with(|b| {
                b.borrow_mut()
                    .as_mut()
                    .map(|ops| ops.push(Op::Rename(tmp.to_path_buf(), path.to_path_buf())))
            })
            .is_some()
    {
        return Ok(());
    }
    rename_into_place(tmp, path)?;
    sync_parent(path)
}

/// Removes `path` (if it exists): now, or at the commit of the thread's open [`Batch`].
pub fn remove_file_durably(path: &Path) -> Result<()> {
    if BATCH
        .with(|b| {
            b.borrow_mut()
                .as_mut()
                .map(|ops| ops.push(Op::Remove(path.to_path_buf())))
        })
        .is_some()
    {
        return Ok(());
    }
    remove_if_present(path)?;
    sync_parent(path)
}

fn remove_if_present(path: &Path) -> Result<()> {
    match fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(Error::io(path, e)),
        _ => Ok(()),
    }
}

fn rename_into_place(tmp: &Path, path: &Path) -> Result<()> {
    fs::rename(tmp, path).map_err(|e| Error::io(path, e))?;
    // Renaming a hard link onto another link of the same file succeeds and does nothing
    // (POSIX): the temporary name would stay.
    if fs::symlink_metadata(tmp).is_ok() {
        fs::remove_file(tmp).map_err(|e| Error::io(tmp, e))?;
    }
    Ok(())
}

/// `fsync`s the directory holding `path`, so a rename or removal in it survives a power cut.
pub fn sync_parent(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    sync_dir(dir)
}

/// `fsync`s a directory. Filesystems that cannot sync a directory (they say `EINVAL`) are let be.
pub fn sync_dir(dir: &Path) -> Result<()> {
    let synced = fs::File::open(dir).and_then(|d| d.sync_all());
    match synced {
        Err(e)
            if !matches!(
                e.kind(),
                std::io::ErrorKind::InvalidInput | std::io::ErrorKind::Unsupported
            ) =>
        {
            Err(Error::io(dir, e))
        }
        _ => Ok(()),
    }
}

enum Op {
    Rename(PathBuf, PathBuf),
    Remove(PathBuf),
}

thread_local! {
    static BATCH: RefCell<Option<Vec<Op>>> = const { RefCell::new(None) };
}

/// Holds back, on this thread, the renames and removals of the atomic writes above until
/// [`Batch::commit`]: the files of a group are all written and synced before any becomes
/// visible. Dropped without a commit (an error, a panic), it removes the temporary files, so
/// nothing of the group appears and what was there stays. The commit renames in order; a kill in
/// the middle of it can leave some files of the group new and some old, each one whole.
#[must_use = "a batch that is not committed removes what was written"]
pub struct Batch {
    _not_send: std::marker::PhantomData<*const ()>,
}

impl Batch {
    /// Opens a batch on this thread; batches do not nest.
    pub fn begin() -> Self {
        BATCH.with(|b| {
            let mut b = b.borrow_mut();
            assert!(b.is_none(), "atomic::Batch does not nest");
            *b = Some(Vec::new());
        });
        Batch {
            _not_send: std::marker::PhantomData,
        }
    }

    fn take() -> Vec<Op> {
        BATCH.with(|b| b.borrow_mut().take()).unwrap_or_default()
    }

    /// Makes every file of the batch visible, then syncs each directory it touched.
    pub fn commit(self) -> Result<()> {
        let ops = Self::take();
        let mut dirs: Vec<PathBuf> = Vec::new();
        let mut outcome = Ok(());
        for op in &ops {
            let (done, path) = match op {
                Op::Rename(tmp, path) if outcome.is_ok() => (rename_into_place(tmp, path), path),
                Op::Remove(path) if outcome.is_ok() => (remove_if_present(path), path),
                Op::Rename(tmp, _) => {
                    let _ = fs::remove_file(tmp);
                    continue;
                }
                Op::Remove(_) => continue,
            };
            outcome = done;
            let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
            if !dirs.contains(&dir) {
                dirs.push(dir);
            }
        }
        outcome?;
        dirs.iter().try_for_each(|d| {
            sync_dir(if d.as_os_str().is_empty() {
                Path::new(".")
            } else {
                d
            })
        })
    }
}

impl Drop for Batch {
    fn drop(&mut self) {
        for op in Self::take() {
            if let Op::Rename(tmp, _) = op {
                let _ = fs::remove_file(tmp);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn failed_write_leaves_no_trace() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("a.bin");
        let err = write_atomically(&target, |tmp| {
            fs::write(tmp, b"half").unwrap();
            Err(Error::format(tmp, "simulated failure"))
        });
        assert!(err.is_err());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn successful_write_replaces_target() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("a.bin");
        fs::write(&target, b"old").unwrap();
        write_bytes_atomically(&target, b"new").unwrap();
        assert_eq!(fs::read(&target).unwrap(), b"new");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn an_unwritable_target_names_the_final_path_and_the_os_error_once() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("missing").join("a.bin");
        let e = write_bytes_atomically(&target, b"x").unwrap_err();
        let text = anyhow_like(&e).to_string();
        assert!(
            text.contains("missing/a.bin") && !text.contains(TEMP_MARK),
            "{text}"
        );
        assert_eq!(text.matches("os error 2").count(), 1, "{text}");
    }

    /// What `{:#}` of an error chain prints: every source's message after the error's own.
    fn anyhow_like(e: &(dyn std::error::Error + 'static)) -> String {
        let mut text = e.to_string();
        let mut source = e.source();
        while let Some(s) = source {
            text.push_str(&format!(": {s}"));
            source = s.source();
        }
        text
    }

    #[test]
    fn temp_names_carry_their_owner() {
        let t = temp_sibling(Path::new("/x/a.png"));
        let name = t.file_name().unwrap().to_string_lossy();
        assert!(is_temp_name(&name), "{name}");
        assert_eq!(temp_owner(&name), Some(std::process::id()));
        assert_eq!(temp_owner(".a.png.partial-123"), Some(123));
        assert_ne!(
            temp_sibling(Path::new("/x/a.png")),
            t,
            "two temp names of one target differ"
        );
    }

    #[test]
    fn a_batch_shows_nothing_until_commit_and_nothing_at_all_when_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        fs::write(&b, b"old b").unwrap();
        {
            let _batch = Batch::begin();
            write_bytes_atomically(&a, b"new a").unwrap();
            remove_file_durably(&b).unwrap();
            assert!(!a.exists() && b.exists());
        }
        assert_eq!(
            names(dir.path()),
            vec!["b"],
            "a dropped batch removes its temporary files and keeps what was there"
        );
        let batch = Batch::begin();
        write_bytes_atomically(&a, b"new a").unwrap();
        remove_file_durably(&b).unwrap();
        batch.commit().unwrap();
        assert_eq!(names(dir.path()), vec!["a"]);
        assert_eq!(fs::read(&a).unwrap(), b"new a");
    }

    #[test]
    fn renaming_onto_a_link_of_the_same_file_leaves_no_temp_name() {
        let dir = tempfile::tempdir().unwrap();
        let (src, dst) = (dir.path().join("src"), dir.path().join("dst"));
        fs::write(&src, b"x").unwrap();
        fs::hard_link(&src, &dst).unwrap();
        let tmp = temp_sibling(&dst);
        fs::hard_link(&src, &tmp).unwrap();
        place(&tmp, &dst).unwrap();
        assert_eq!(names(dir.path()), vec!["dst", "src"]);
    }
}
