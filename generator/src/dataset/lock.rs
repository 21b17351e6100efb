//! The lock that makes one process the only writer of a dataset directory, on local disks and on
//! shared filesystems where `flock` may be a no-op or local to one client (NFS).
//!
//! Taking it: the holder's description (host, pid, start time, command) is written to a unique
//! temporary file, which is then hard-linked to `.stereogen.lock`. `link` fails if the name
//! exists and is atomic on NFS (the classic NFS lock; `O_EXCL` creation is not atomic on NFSv2),
//! and the lock appears with its contents complete. While held, a thread touches the file every
//! [`HEARTBEAT`] (with the filesystem's clock, so clients' clocks need not agree).
//!
//! A lock is **stale** when its holder cannot be running: on this host, its pid is gone (or was
//! reused by a process started later); on another host, its heartbeat stopped more than
//! [`STALE_AFTER`] ago. A stale lock is broken (with a warning naming the holder), so a task
//! killed with SIGKILL does not block its re-run. `--break-lock` breaks any lock. An empty lock
//! file is one an older stereogen left (it used `flock`): free unless still `flock`ed.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::{Context, bail};
use fs4::fs_std::FileExt;
use serde::{Deserialize, Serialize};

/// How often a holder touches its lock file.
pub const HEARTBEAT: Duration = Duration::from_secs(30);
/// A lock of another host whose heartbeat is older than this is stale.
pub const STALE_AFTER: Duration = Duration::from_secs(300);
/// A breaker file (the guard of breaking a stale lock) older than this was left by a crash.
const BREAKER_STALE_AFTER: Duration = Duration::from_secs(60);

/// Who holds a lock: the lock file's contents.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LockHolder {
    pub host: String,
    pub pid: u32,
    pub started_unix_s: u64,
    /// The same instant, readable: `2026-11-23T02:10:00Z`.
    pub started: String,
    pub stereogen_version: String,
    /// The holder's command line.
    pub command: String,
}

impl LockHolder {
    fn this_process() -> Self {
        let now = unix_now();
        Self {
            host: hostname(),
            pid: std::process::id(),
            started_unix_s: now,
            started: utc_timestamp(now),
            stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
            command: std::env::args().collect::<Vec<_>>().join(" "),
        }
    }

    /// `pid 1234 on host node7 since 2026-11-23T02:10:00Z`.
    pub fn describe(&self) -> String {
        format!(
            "pid {} on host {} since {}",
            self.pid, self.host, self.started
        )
    }
}

/// What a lock file says about its directory.
#[derive(Debug, Clone, PartialEq)]
pub enum LockState {
    Free,
    /// Held by a process that may be running; `heartbeat_age` is how long ago it last touched it.
    Held {
        holder: LockHolder,
        heartbeat_age: Duration,
    },
    /// Held by a process that cannot be running (why in words).
    Stale {
        holder: Option<LockHolder>,
        why: String,
    },
    /// An older stereogen's `flock` on an empty lock file is held.
    LegacyHeld,
}

/// Reads the lock at `path` and judges it.
pub fn inspect(path: &Path) -> LockState {
    let Ok(bytes) = std::fs::read(path) else {
        return LockState::Free;
    };
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return match File::open(path).map(|f| f.try_lock_exclusive()) {
            Ok(Ok(true)) => LockState::Stale {
                holder: None,
                why: "an empty lock file left by an older stereogen".into(),
            },
            Ok(_) => LockState::LegacyHeld,
            Err(_) => LockState::Free,
        };
    }
    let Ok(holder) = serde_json::from_slice::<LockHolder>(&bytes) else {
        return LockState::Stale {
            holder: None,
            why: "the lock file is not a stereogen lock (damaged)".into(),
        };
    };
    let heartbeat_age = std::fs::metadata(path)
        .ok()
        .and_then(|m| m.modified().ok())
        .map(|m| age_on_filesystem(path, m))
        .unwrap_or_default();
    match staleness(&holder, heartbeat_age) {
        Some(why) => LockState::Stale {
            holder: Some(holder),
            why,
        },
        None => LockState::Held {
            holder,
            heartbeat_age,
        },
    }
}

/// Why `holder` cannot be running, or `None` if it may be.
fn staleness(holder: &LockHolder, heartbeat_age: Duration) -> Option<String> {
    if holder.host == hostname() {
        return match process_start_unix_s(holder.pid) {
            None => Some(format!("pid {} is not running on this host", holder.pid)),
            // /proc's start time is whole seconds after boot; allow for the rounding.
            Some(t) if t > holder.started_unix_s + 2 => Some(format!(
                "pid {} now belongs to a process started after the lock",
                holder.pid
            )),
            Some(_) => None,
        };
    }
    (heartbeat_age > STALE_AFTER).then(|| {
        format!(
            "no heartbeat from host {} for {} s",
            holder.host,
            heartbeat_age.as_secs()
        )
    })
}

/// A held lock: removed (if still ours) when dropped.
pub struct DatasetLock {
    path: PathBuf,
    holder: LockHolder,
    heartbeat: Option<Heartbeat>,
}

impl DatasetLock {
    /// Takes the lock at `path`, breaking a stale one (or any, with `break_lock`). Fails at once
    /// when another process holds it, naming that process.
    pub fn acquire(path: &Path, break_lock: bool) -> anyhow::Result<Self> {
        let holder = LockHolder::this_process();
        let contents = serde_json::to_vec_pretty(&holder).expect("a lock holder serialises");
        // Breaking a stale lock can race with another process doing the same; two rounds suffice
        // for the loser to see the winner's fresh lock.
        for _ in 0..3 {
            if try_create(path, &contents)? {
                let heartbeat = start_heartbeat(path.to_path_buf());
                return Ok(Self {
                    path: path.to_path_buf(),
                    holder,
                    heartbeat: Some(heartbeat),
                });
            }
            match inspect(path) {
                LockState::Free => {}
                LockState::Held {
                    holder: other,
                    heartbeat_age,
                } if !break_lock => bail!(
                    "{} is being written by {} (lock file {}, heartbeat {} s ago); wait for it to finish, or if that process is gone pass --break-lock",
                    dir_of(path).display(),
                    other.describe(),
                    path.display(),
                    heartbeat_age.as_secs()
                ),
                LockState::LegacyHeld if !break_lock => bail!(
                    "{} is being written by an older stereogen process (it holds {} with flock); wait for it to finish",
                    dir_of(path).display(),
                    path.display()
                ),
                state => break_stale(path, &state)?,
            }
        }
        bail!(
            "cannot take the lock {}: other processes keep taking it",
            path.display()
        )
    }

    pub fn holder(&self) -> &LockHolder {
        &self.holder
    }
}

impl Drop for DatasetLock {
    fn drop(&mut self) {
        if let Some(Heartbeat { stop, thread }) = self.heartbeat.take() {
            *stop.0.lock().unwrap() = true;
            stop.1.notify_all();
            let _ = thread.join();
        }
        // Only our own lock: after --break-lock by someone else the file is theirs.
        let ours = std::fs::read(&self.path)
            .ok()
            .and_then(|b| serde_json::from_slice::<LockHolder>(&b).ok())
            .is_some_and(|h| h == self.holder);
        if ours {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

fn dir_of(path: &Path) -> &Path {
    path.parent().unwrap_or(Path::new("."))
}

/// Links a complete lock file into place; `false` when the name is taken.
fn try_create(path: &Path, contents: &[u8]) -> anyhow::Result<bool> {
    let tmp = dir_of(path).join(format!(
        ".stereogen.lock.{}.{}.{}",
        hostname(),
        std::process::id(),
        unix_nanos()
    ));
    let mut file =
        File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    file.write_all(contents)
        .and_then(|()| file.sync_all())
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    drop(file);
    let linked =
        match std::fs::hard_link(&tmp, path) {
            Ok(()) => Ok(true),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
            // NFS may report an error for a link that was made (a lost reply): the link count says.
            Err(e) => match std::fs::metadata(&tmp) {
                Ok(m) if m.nlink() == 2 => Ok(true),
                _ => Err(anyhow::Error::new(e)
                    .context(format!("cannot create the lock {}", path.display()))),
            },
        };
    let _ = std::fs::remove_file(&tmp);
    linked
}

/// Removes a stale (or, with --break-lock, any) lock, guarded by a breaker file so that two
/// processes breaking the same lock cannot remove each other's fresh one.
fn break_stale(path: &Path, judged: &LockState) -> anyhow::Result<()> {
    let breaker = path.with_extension("lock.break");
    match OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&breaker)
    {
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            let old = std::fs::metadata(&breaker)
                .ok()
                .and_then(|m| m.modified().ok())
                .map(|m| age_on_filesystem(path, m))
                .unwrap_or_default();
            if old > BREAKER_STALE_AFTER {
                let _ = std::fs::remove_file(&breaker);
            }
            std::thread::sleep(Duration::from_millis(200));
            return Ok(());
        }
        Err(e) => {
            return Err(
                anyhow::Error::new(e).context(format!("cannot create {}", breaker.display()))
            );
        }
    }
    // Still the lock we judged? (Another process may have broken it and taken the lock since.)
    let now = inspect(path);
    let same = match (judged, &now) {
        (
            LockState::Held { holder: a, .. }
            | LockState::Stale {
                holder: Some(a), ..
            },
            LockState::Held { holder: b, .. }
            | LockState::Stale {
                holder: Some(b), ..
            },
        ) => a == b,
        (a, b) => std::mem::discriminant(a) == std::mem::discriminant(b),
    };
    if same && now != LockState::Free {
        let why = match &now {
            LockState::Stale { why, .. } => why.clone(),
            _ => "--break-lock".into(),
        };
        let who = match &now {
            LockState::Held { holder, .. }
            | LockState::Stale {
                holder: Some(holder),
                ..
            } => holder.describe(),
            _ => "an older stereogen".into(),
        };
        tracing::warn!("breaking the lock {} held by {who}: {why}", path.display());
        let _ = std::fs::remove_file(path);
    }
    let _ = std::fs::remove_file(&breaker);
    Ok(())
}

/// The thread touching a held lock, and how to stop it.
struct Heartbeat {
    stop: Arc<(Mutex<bool>, Condvar)>,
    thread: JoinHandle<()>,
}

/// Touches the lock every [`HEARTBEAT`] until told to stop.
fn start_heartbeat(path: PathBuf) -> Heartbeat {
    let stop = Arc::new((Mutex::new(false), Condvar::new()));
    let signal = Arc::clone(&stop);
    let thread = std::thread::spawn(move || {
        let (flag, cvar) = &*signal;
        let mut stopped = flag.lock().unwrap();
        loop {
            // `_while` checks the flag first: a stop set before this thread waits is not missed.
            stopped = cvar
                .wait_timeout_while(stopped, HEARTBEAT, |stop| !*stop)
                .unwrap()
                .0;
            if *stopped {
                break;
            }
            if let Err(e) = touch(&path) {
                tracing::warn!("cannot refresh the lock {}: {e}", path.display());
            }
        }
    });
    Heartbeat { stop, thread }
}

/// Sets the file's times to "now" as its filesystem sees it (NFS: the server's clock).
fn touch(path: &Path) -> std::io::Result<()> {
    let file = File::open(path)?;
    use std::os::fd::AsRawFd;
    // SAFETY: a valid open descriptor; a null `times` means "now" for both times.
    if unsafe { libc::futimens(file.as_raw_fd(), std::ptr::null()) } == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// How long ago `then` was, by the clock of the filesystem holding `near` (a fresh file's mtime),
/// falling back to this machine's clock.
fn age_on_filesystem(near: &Path, then: SystemTime) -> Duration {
    let probe = dir_of(near).join(format!(
        ".stereogen.clock.{}.{}",
        std::process::id(),
        unix_nanos()
    ));
    let now = File::create(&probe)
        .and_then(|f| f.metadata())
        .and_then(|m| m.modified())
        .unwrap_or_else(|_| SystemTime::now());
    let _ = std::fs::remove_file(&probe);
    now.duration_since(then).unwrap_or_default()
}

/// This machine's name (`gethostname`).
pub fn hostname() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: the buffer is valid for its length; the result is NUL-terminated or truncated.
    let ok = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } == 0;
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    if ok && end > 0 {
        String::from_utf8_lossy(&buf[..end]).into_owned()
    } else {
        "unknown-host".into()
    }
}

/// When process `pid` started (Unix seconds), or `None` if no such process runs here.
fn process_start_unix_s(pid: u32) -> Option<u64> {
    // SAFETY: signal 0 only checks that the process exists.
    let alive = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0
        || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
    if !alive {
        return None;
    }
    let start = || -> Option<u64> {
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
        // Field 22 (starttime, clock ticks after boot); the command (field 2) may hold spaces.
        let ticks: u64 = stat
            .rsplit_once(')')?
            .1
            .split_whitespace()
            .nth(19)?
            .parse()
            .ok()?;
        let boot: u64 = std::fs::read_to_string("/proc/stat")
            .ok()?
            .lines()
            .find_map(|l| l.strip_prefix("btime "))?
            .trim()
            .parse()
            .ok()?;
        // SAFETY: sysconf has no preconditions.
        let hz = u64::try_from(unsafe { libc::sysconf(libc::_SC_CLK_TCK) })
            .ok()
            .filter(|&h| h > 0)?;
        Some(boot + ticks / hz)
    };
    // Alive but its start unknown (no /proc): it may be the holder.
    Some(start().unwrap_or(0))
}

pub fn unix_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

fn unix_nanos() -> u128 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0)
}

/// `2026-11-23T02:10:00Z` for Unix seconds (proleptic Gregorian calendar, UTC).
pub fn utc_timestamp(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let secs = unix_s % 86_400;
    // Days to civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        secs / 3600,
        secs / 60 % 60,
        secs % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_are_utc_calendar_dates() {
        assert_eq!(utc_timestamp(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_timestamp(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_timestamp(1_795_400_000), "2026-11-23T02:13:20Z");
    }

    #[test]
    fn a_second_taker_fails_naming_the_holder_and_the_lock_goes_with_its_holder() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(".stereogen.lock");
        let lock = DatasetLock::acquire(&path, false).unwrap();
        let e = DatasetLock::acquire(&path, false)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains(&format!("pid {}", std::process::id()))
                && e.contains(&hostname())
                && e.contains("--break-lock"),
            "{e}"
        );
        assert!(matches!(inspect(&path), LockState::Held { .. }));
        drop(lock);
        assert!(!path.exists());
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert!(left.is_empty(), "no temporary files left: {left:?}");
    }

    #[test]
    fn dead_or_reused_pids_and_old_empty_files_are_stale_and_broken() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(".stereogen.lock");
        let mut holder = LockHolder::this_process();
        // A pid that has exited: a child we waited for.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        holder.pid = child.id();
        child.wait().unwrap();
        std::fs::write(&path, serde_json::to_vec(&holder).unwrap()).unwrap();
        assert!(
            matches!(inspect(&path), LockState::Stale { why, .. } if why.contains("not running"))
        );
        let lock = DatasetLock::acquire(&path, false).unwrap();
        assert_eq!(lock.holder().pid, std::process::id());
        drop(lock);

        // Our own pid, but a lock older than this process: the pid was reused.
        holder.pid = std::process::id();
        holder.started_unix_s = 1000;
        std::fs::write(&path, serde_json::to_vec(&holder).unwrap()).unwrap();
        assert!(
            matches!(inspect(&path), LockState::Stale { why, .. } if why.contains("started after"))
        );

        std::fs::write(&path, "").unwrap();
        assert!(matches!(
            inspect(&path),
            LockState::Stale { holder: None, .. }
        ));
        drop(DatasetLock::acquire(&path, false).unwrap());
    }

    #[test]
    fn another_hosts_lock_is_stale_only_without_heartbeat_and_break_lock_takes_any() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(".stereogen.lock");
        let mut holder = LockHolder::this_process();
        holder.host = "elsewhere".into();
        std::fs::write(&path, serde_json::to_vec(&holder).unwrap()).unwrap();
        assert!(matches!(inspect(&path), LockState::Held { .. }));
        let e = DatasetLock::acquire(&path, false)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("on host elsewhere"), "{e}");
        let old = SystemTime::now() - STALE_AFTER - Duration::from_secs(60);
        File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(old)
            .unwrap();
        assert!(
            matches!(inspect(&path), LockState::Stale { why, .. } if why.contains("no heartbeat"))
        );
        std::fs::write(&path, serde_json::to_vec(&holder).unwrap()).unwrap();
        let lock = DatasetLock::acquire(&path, true).unwrap();
        assert_eq!(lock.holder().host, hostname());
    }
}
