//! Python environments for tests and benches that check our files with code nobody here wrote
//! (OpenCV, Pillow, OpenEXR, the maturin-built module): one venv per set of pinned packages under
//! `$STEREOGEN_HOME/python` (default `~/.cache/stereogen/python`), made once and reused.
//!
//! Every test and bench that needs such an environment makes it here (stereo-io's conformance
//! tests, the trainer's export tests, the e2e Python tests, stereogen-py's decode bench), so there
//! is one way to make one.

use std::path::{Path, PathBuf};
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
pub fn python_home() -> PathBuf {
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
    ensure_venv_made(name, pins, |venv| {
        run(pip_install(venv).args(pins), "pip install");
    })
}

/// The venv `<name>-<pins>` that sees the packages of the venv `base` (a `.pth` file naming its
/// site-packages) and adds `pins` installed without their dependencies. For a package whose
/// newest release names an older version of something `base` already holds (torchvision 0.29
/// asks for torch 2.14, the trainer's parity venv has torch 2.15) without a second copy of
/// several gigabytes. Made like [`ensure_venv`].
pub fn ensure_venv_on(base: &Path, name: &str, pins: &[&str]) -> PathBuf {
    ensure_venv_made(name, pins, |venv| {
        run(
            pip_install(venv).arg("--no-deps").args(pins),
            "pip install --no-deps",
        );
        let site = |python: PathBuf| {
            let code = "import sysconfig; print(sysconfig.get_paths()['purelib'])";
            let out = run(
                Command::new(python).args(["-c", code]),
                "python -c sysconfig",
            );
            PathBuf::from(out.trim())
        };
        let base_site = site(base.join("bin/python"));
        std::fs::write(
            site(venv.join("bin/python")).join("base-venv.pth"),
            format!("{}\n", base_site.display()),
        )
        .unwrap();
    })
}

/// `<name>-<pins>` (`numpy==2.4.6` written `numpy2.4.6`, joined by `-`); a list too long for a
/// file name is named by its FNV-1a hash instead (`<name>-<16 hex digits>`).
fn venv_dir_name(name: &str, pins: &[&str]) -> String {
    let joined = pins.join("-").replace("==", "");
    if joined.len() <= 160 {
        return format!("{name}-{joined}");
    }
    let hash = joined.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{name}-{hash:016x}")
}

fn ensure_venv_made(name: &str, pins: &[&str], install: impl FnOnce(&Path)) -> PathBuf {
    let base = python_home();
    std::fs::create_dir_all(&base).unwrap();
    let lock = std::fs::File::create(base.join(".lock")).unwrap();
    lock.lock().expect("lock the Python environments");
    let venv = base.join(venv_dir_name(name, pins));
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
        install(&tmp);
        std::fs::write(tmp.join(".complete"), pins.join("\n")).unwrap();
        // A venv's python finds its packages relative to pyvenv.cfg, so the move is harmless.
        std::fs::rename(&tmp, &venv).unwrap();
    }
    venv
}
