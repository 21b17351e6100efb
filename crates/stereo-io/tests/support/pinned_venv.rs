//! Python environments for tests and benches that check our files with code nobody here wrote
//! (OpenCV, Pillow, OpenEXR, the maturin-built module): one venv per set of pinned packages under
//! `$STEREOGEN_HOME/python` (default `~/.cache/stereogen/python`), made once and reused.
//!
//! Shared by `#[path]` (stereo-io's conformance test, the e2e Python test, stereogen-py's decode
//! bench), so there is one way to make such an environment.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// Runs `cmd`; panics with its output unless it succeeds. Returns its stdout.
pub fn run(cmd: &mut Command, what: &str) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot start: {e}"));
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `$STEREOGEN_HOME/python`, the rule of `stereogen_assets::stereogen_home` (which the crates
/// sharing this file cannot all depend on).
fn python_home() -> PathBuf {
    std::env::var_os("STEREOGEN_HOME")
        .filter(|h| !h.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(std::env::var("HOME").expect("HOME")).join(".cache/stereogen")
        })
        .join("python")
}

/// `pip install` (quiet) run by the Python of `venv`; the packages are the caller's arguments.
pub fn pip_install(venv: &std::path::Path) -> Command {
    let mut c = Command::new(venv.join("bin/python"));
    c.args([
        "-m",
        "pip",
        "install",
        "--quiet",
        "--disable-pip-version-check",
    ]);
    c
}

/// The venv `<name>-<pins>` with `pins` installed: made under a temporary name by
/// `$STEREOGEN_BOOTSTRAP_PYTHON` (default `python3`), renamed into place once complete, under a
/// file lock so parallel test processes wait for one install.
pub fn ensure_venv(name: &str, pins: &[&str]) -> PathBuf {
    let base = python_home();
    std::fs::create_dir_all(&base).unwrap();
    let lock = std::fs::File::create(base.join(".lock")).unwrap();
    lock.lock().expect("lock the Python environments");
    let venv = base.join(format!("{name}-{}", pins.join("-").replace("==", "")));
    if !venv.join(".complete").is_file() {
        let python =
            std::env::var("STEREOGEN_BOOTSTRAP_PYTHON").unwrap_or_else(|_| "python3".into());
        let tmp = base.join(format!(".{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        let _ = std::fs::remove_dir_all(&venv);
        run(
            Command::new(&python).args(["-m", "venv"]).arg(&tmp),
            "python3 -m venv",
        );
        run(pip_install(&tmp).args(pins), "pip install");
        std::fs::write(tmp.join(".complete"), pins.join("\n")).unwrap();
        // A venv's python finds its packages relative to pyvenv.cfg, so the move is harmless.
        std::fs::rename(&tmp, &venv).unwrap();
    }
    venv
}
