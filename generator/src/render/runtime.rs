//! Finding Blender's Python, and installing the managed `bpy` environment when there is none.
//!
//! Order: `--blender PATH` (a Blender executable), `STEREOGEN_PYTHON` (a Python that imports
//! `bpy`), then the managed virtual environment `$STEREOGEN_HOME/blender/bpy-<version>`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use fs4::fs_std::FileExt;

pub use stereogen_assets::stereogen_home;

pub use stereogen_assets::blender_env::{
    BPY_VERSION, TRIMESH_VERSION, managed_env_dir, managed_envs_root, managed_python,
};
/// The Blender series every runtime must report.
pub const BLENDER_SERIES: &str = "4.5";
/// The Python minor version the `bpy` 4.5 wheels are built for.
pub const BPY_PYTHON: (u32, u32) = (3, 11);

#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    #[error("--blender {0}: no such file; give the path of a Blender {BLENDER_SERIES} executable")]
    MissingBlender(PathBuf),
    #[error(
        "STEREOGEN_PYTHON={0}: no such file; point it at a Python that can `import bpy`, or unset it"
    )]
    MissingPython(PathBuf),
    #[error(
        "no Blender runtime installed; run `stereogen setup` (installs bpy {BPY_VERSION} under {0})"
    )]
    NotInstalled(PathBuf),
    #[error(
        "cannot run {program}: {message}; bpy {BPY_VERSION} needs Python {}.{}: install it or set \
         STEREOGEN_BOOTSTRAP_PYTHON to a python3.11",
        BPY_PYTHON.0,
        BPY_PYTHON.1
    )]
    NoBootstrapPython { program: String, message: String },
    #[error(
        "{program} is Python {found}; bpy {BPY_VERSION} wheels exist only for Python {}.{}: set \
         STEREOGEN_BOOTSTRAP_PYTHON to a python3.11, or pass --blender",
        BPY_PYTHON.0,
        BPY_PYTHON.1
    )]
    WrongPython { program: String, found: String },
    #[error(
        "setting up the Blender environment failed at `{step}`: {message}; nothing was installed, fix the cause and run `stereogen setup` again"
    )]
    SetupFailed { step: String, message: String },
    #[error("{0}")]
    Io(String),
}

/// A way to run Python inside Blender.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BlenderRuntime {
    /// A `blender` executable, run in background mode.
    Executable(PathBuf),
    /// A Python interpreter that can `import bpy`.
    Python(PathBuf),
}

impl BlenderRuntime {
    /// The command that runs `script` with `args` inside this runtime.
    pub fn command(&self, script: &Path, args: &[String]) -> Command {
        match self {
            BlenderRuntime::Executable(blender) => {
                let mut c = Command::new(blender);
                c.args([
                    "-b",
                    "--factory-startup",
                    "--python-exit-code",
                    "1",
                    "--python",
                ])
                .arg(script)
                .arg("--")
                .args(args);
                c
            }
            BlenderRuntime::Python(python) => {
                let mut c = Command::new(python);
                c.arg("-u").arg(script).args(args);
                c
            }
        }
    }

    pub fn describe(&self) -> String {
        match self {
            BlenderRuntime::Executable(p) => format!("blender executable {}", p.display()),
            BlenderRuntime::Python(p) => format!("python {}", p.display()),
        }
    }
}

/// The current environment's folder name (an install in progress is named after it).
fn managed_env_name(home: &Path) -> String {
    let dir = managed_env_dir(home);
    dir.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Picks the runtime by the documented order, without installing anything.
pub fn discover(
    explicit_blender: Option<&Path>,
    home: &Path,
) -> Result<BlenderRuntime, RuntimeError> {
    if let Some(b) = explicit_blender {
        return if b.is_file() {
            Ok(BlenderRuntime::Executable(b.to_path_buf()))
        } else {
            Err(RuntimeError::MissingBlender(b.to_path_buf()))
        };
    }
    if let Some(p) = std::env::var_os("STEREOGEN_PYTHON").filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(BlenderRuntime::Python(p))
        } else {
            Err(RuntimeError::MissingPython(p))
        };
    }
    let managed = managed_python(home);
    if managed.is_file() {
        Ok(BlenderRuntime::Python(managed))
    } else {
        Err(RuntimeError::NotInstalled(managed_env_dir(home)))
    }
}

/// Like [`discover`], but installs the managed environment when nothing else is configured.
pub fn discover_or_install(
    explicit_blender: Option<&Path>,
    home: &Path,
) -> Result<BlenderRuntime, RuntimeError> {
    match discover(explicit_blender, home) {
        Err(RuntimeError::NotInstalled(_)) => install_managed(home).map(BlenderRuntime::Python),
        other => other,
    }
}

fn run_step(step: &str, cmd: &mut Command) -> Result<(), RuntimeError> {
    tracing::debug!("setup: {step}: {cmd:?}");
    let status = cmd.status().map_err(|e| RuntimeError::SetupFailed {
        step: step.into(),
        message: e.to_string(),
    })?;
    if status.success() {
        Ok(())
    } else {
        Err(RuntimeError::SetupFailed {
            step: step.into(),
            message: format!("exited with {status}"),
        })
    }
}

fn check_bootstrap_python(program: &str) -> Result<(), RuntimeError> {
    let out = Command::new(program)
        .args(["-c", "import sys; print('%d.%d.%d' % sys.version_info[:3])"])
        .output()
        .map_err(|e| RuntimeError::NoBootstrapPython {
            program: program.into(),
            message: e.to_string(),
        })?;
    if !out.status.success() {
        return Err(RuntimeError::NoBootstrapPython {
            program: program.into(),
            message: format!("its version check exited with {}", out.status),
        });
    }
    let found = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let want = format!("{}.{}.", BPY_PYTHON.0, BPY_PYTHON.1);
    if !found.starts_with(&want) {
        return Err(RuntimeError::WrongPython {
            program: program.into(),
            found,
        });
    }
    Ok(())
}

/// Creates `$STEREOGEN_HOME/blender/bpy-<version>` with `python3 -m venv` and pip.
///
/// The environment is built under a temporary name and renamed into place only after `import bpy`
/// works, so a failure or a kill leaves nothing half-installed. A file lock makes concurrent
/// callers (parallel tests, several generators on one host) wait for one install.
pub fn install_managed(home: &Path) -> Result<PathBuf, RuntimeError> {
    let io = |what: &str, e: std::io::Error| RuntimeError::Io(format!("{what}: {e}"));
    let parent = managed_envs_root(home);
    std::fs::create_dir_all(&parent)
        .map_err(|e| io(&format!("cannot create {}", parent.display()), e))?;
    let lock_path = parent.join(".setup.lock");
    let lock = std::fs::File::create(&lock_path)
        .map_err(|e| io(&format!("cannot create {}", lock_path.display()), e))?;
    lock.lock_exclusive()
        .map_err(|e| io("cannot lock the Blender environment", e))?;

    let final_dir = managed_env_dir(home);
    let python = managed_python(home);
    if python.is_file() {
        return Ok(python);
    }
    // Leftovers of an install that was killed.
    if let Ok(entries) = std::fs::read_dir(&parent) {
        for e in entries.flatten() {
            if e.file_name()
                .to_string_lossy()
                .starts_with(&format!(".{}.tmp-", managed_env_name(home)))
            {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
    let bootstrap = std::env::var("STEREOGEN_BOOTSTRAP_PYTHON")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| {
            // Prefer an explicit 3.11 when the default python3 is another version.
            let v311 = format!("python{}.{}", BPY_PYTHON.0, BPY_PYTHON.1);
            if Command::new(&v311)
                .arg("--version")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
            {
                v311
            } else {
                "python3".into()
            }
        });
    check_bootstrap_python(&bootstrap)?;

    let tmp = parent.join(format!(
        ".{}.tmp-{}",
        managed_env_name(home),
        std::process::id()
    ));
    eprintln!(
        "stereogen: installing Blender {BPY_VERSION} (bpy from PyPI, ~370 MB download) into {} ...",
        final_dir.display()
    );
    let result = (|| {
        run_step(
            "python3 -m venv",
            Command::new(&bootstrap).args(["-m", "venv"]).arg(&tmp),
        )?;
        let tmp_python = tmp.join("bin").join("python");
        run_step(
            "pip install bpy",
            Command::new(&tmp_python)
                .args([
                    "-m",
                    "pip",
                    "install",
                    "--disable-pip-version-check",
                    "--no-input",
                    "--progress-bar",
                    "on",
                ])
                .arg(format!("bpy=={BPY_VERSION}"))
                .arg(format!("trimesh=={TRIMESH_VERSION}"))
                // pip's report goes to stderr: commands such as `plan` print their result on stdout.
                .stdout(std::io::stderr())
                .stderr(Stdio::inherit()),
        )?;
        run_step(
            "import bpy, trimesh",
            Command::new(&tmp_python)
                .args(["-c", "import bpy, trimesh"])
                .stdout(Stdio::null()),
        )?;
        std::fs::rename(&tmp, &final_dir).map_err(|e| RuntimeError::SetupFailed {
            step: "rename into place".into(),
            message: e.to_string(),
        })
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result?;
    eprintln!("stereogen: Blender environment ready: {}", python.display());
    Ok(python)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn explicit_blender_path_must_exist() {
        let err = discover(Some(Path::new("/no/such/blender")), Path::new("/tmp")).unwrap_err();
        assert!(err.to_string().contains("/no/such/blender"));
    }

    #[test]
    fn executable_runtime_runs_blender_in_background() {
        let rt = BlenderRuntime::Executable("/opt/blender/blender".into());
        let cmd = rt.command(Path::new("/s/worker.py"), &["--x".into()]);
        let args: Vec<String> = cmd
            .get_args()
            .map(|a| a.to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            args,
            [
                "-b",
                "--factory-startup",
                "--python-exit-code",
                "1",
                "--python",
                "/s/worker.py",
                "--",
                "--x"
            ]
        );
    }
}
