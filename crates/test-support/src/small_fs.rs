//! A small filesystem of its own for disk-full tests: a size-limited tmpfs mounted on a fresh
//! temporary directory (as root, or through `sudo -n` where that needs no password), unmounted
//! when dropped. Where nothing can be mounted, [`SmallFs::mount`] says why and the caller skips,
//! or fails when `STEREOGEN_REQUIRE_SMALL_FS=1` (as CI sets it).

use std::path::{Path, PathBuf};
use std::process::Command;

pub struct SmallFs {
    dir: tempfile::TempDir,
    sudo: bool,
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

fn mount_cmd(sudo: bool, args: &[&str], dir: &Path) -> Command {
    let mut c = if sudo {
        let mut c = Command::new("sudo");
        c.args(["-n", args[0]]);
        c
    } else {
        Command::new(args[0])
    };
    c.args(&args[1..]).arg(dir);
    c
}

impl SmallFs {
    /// A fresh tmpfs of `bytes` (rounded up to whole pages by the kernel), or why there is none.
    pub fn mount(bytes: u64) -> Result<Self, String> {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let size = format!("size={bytes}");
        let mut tried = Vec::new();
        for sudo in [false, true] {
            if !sudo && !is_root() {
                continue;
            }
            let out = mount_cmd(
                sudo,
                &["mount", "-t", "tmpfs", "-o", &size, "stereogen-test"],
                dir.path(),
            )
            .output();
            match out {
                Ok(o) if o.status.success() => return Ok(Self { dir, sudo }),
                Ok(o) => tried.push(String::from_utf8_lossy(&o.stderr).trim().to_string()),
                Err(e) => tried.push(e.to_string()),
            }
        }
        Err(format!(
            "cannot mount a {bytes}-byte tmpfs (needs root or passwordless sudo): {}",
            tried.join("; ")
        ))
    }

    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Bytes still free for files.
    pub fn free(&self) -> u64 {
        let out = Command::new("df")
            .args(["--output=avail", "-B1"])
            .arg(self.path())
            .output()
            .expect("df");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .nth(1)
            .and_then(|l| l.trim().parse().ok())
            .expect("df prints the free bytes")
    }

    /// Fills the filesystem until `leave` bytes (rounded down to whole pages) are free; returns
    /// the filler, whose removal frees the space again.
    pub fn fill_leaving(&self, leave: u64) -> PathBuf {
        let filler = self.path().join("filler");
        let free = self.free();
        let take = free.saturating_sub(leave);
        std::fs::write(&filler, vec![0u8; take as usize]).expect("fill the small filesystem");
        filler
    }
}

impl Drop for SmallFs {
    fn drop(&mut self) {
        let _ = mount_cmd(self.sudo, &["umount", "-l"], self.dir.path()).status();
    }
}

/// Whether the disk-full tests must run: `STEREOGEN_REQUIRE_SMALL_FS=1` (set by CI) turns a file
/// system that cannot be mounted into a failure instead of a skip.
pub fn small_fs_required() -> bool {
    std::env::var("STEREOGEN_REQUIRE_SMALL_FS").is_ok_and(|v| v == "1")
}

/// Skips the calling test, saying why, when `fs` could not be mounted; fails it instead when
/// [`small_fs_required`].
#[macro_export]
macro_rules! small_fs_or_skip {
    ($bytes:expr) => {
        match $crate::small_fs::SmallFs::mount($bytes) {
            Ok(fs) => fs,
            Err(why) if $crate::small_fs::small_fs_required() => {
                panic!("STEREOGEN_REQUIRE_SMALL_FS=1 but no small file system could be mounted: {why}")
            }
            Err(why) => {
                eprintln!("SKIPPED (no small filesystem; STEREOGEN_REQUIRE_SMALL_FS=1 makes this fail): {why}");
                return;
            }
        }
    };
}
