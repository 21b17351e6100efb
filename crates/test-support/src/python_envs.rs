//! The Python environments of the tests that use the `stereogen` wheel as its users do (with
//! PyTorch, `datasets` and `webdataset`): one base venv with those packages, pinned and installed
//! without their dependencies on top of the PyTorch venv the other PyTorch tests share (so there
//! is one copy of PyTorch), and venvs made anew for each run on top of it, so the wheel under test
//! is installed into a fresh environment every time.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

pub use crate::pinned_venv;

/// The PyTorch venv of the `.pth` export and torchvision tests.
pub const TORCH_PINS: &[&str] = &["torch==2.15.0", "numpy==2.4.6"];

/// `datasets` and `webdataset` with everything they import (pip's own resolution of
/// `datasets==5.2.0 webdataset==1.0.2` beside torch 2.15, written out so nothing floats).
pub const HUB_PINS: &[&str] = &[
    "datasets==5.2.0",
    "webdataset==1.0.2",
    "anyio==4.16.0",
    "braceexpand==0.1.7",
    "click==8.5.1",
    "dill==0.4.1",
    "filelock==4.3.1",
    "fsspec==2026.9.0",
    "h11==0.16.0",
    "hf-xet==1.8.0",
    "httpcore2==2.16.2",
    "httpx2==2.16.2",
    "huggingface_hub==2.4.0",
    "idna==3.20",
    "multiprocess==0.70.19",
    "packaging==26.4",
    "pandas==3.1.1",
    "pillow==13.0.0",
    "pyarrow==26.0.1",
    "python-dateutil==4.0.0",
    "PyYAML==6.0.4",
    "tqdm==4.70.1",
    "truststore==0.10.5",
    "typing_extensions==4.16.0",
    "tzdata==2026.6",
    "xxhash==4.1.0",
];

/// The venv with maturin that builds the module for the other Python tests
/// (tests/integration/io_python.rs).
pub const MATURIN_PINS: &[&str] = &["maturin==1.16.0", "pytest==9.0.2", "numpy==2.4.6"];

/// Builds the `stereogen` Python module (crates/stereogen-py) with `venv`'s maturin and installs
/// the wheel into `venv`. The build goes to `<target>/python-ext`, a cargo folder of its own:
/// maturin's build environment would otherwise invalidate the workspace's pyo3 build, and one
/// folder for every maturin build of the tests (this, the wheel tests, the README's wheel block;
/// one at a time, `turns::python_ext`) compiles the module's crates once per run.
///
/// Once per venv in a test process: the end-to-end tests run side by side in one binary, and two
/// `pip install`s into one venv at once would race (a second one would also be work for nothing).
pub fn install_stereogen_module(venv: &Path) {
    static INSTALLED: Mutex<BTreeSet<PathBuf>> = Mutex::new(BTreeSet::new());
    let mut installed = INSTALLED.lock().unwrap_or_else(|p| p.into_inner());
    if installed.contains(venv) {
        return;
    }
    let wheels = tempfile::tempdir().unwrap();
    let _turn = crate::turns::python_ext();
    pinned_venv::run(
        Command::new(venv.join("bin/maturin"))
            .args([
                "build",
                "--release",
                "--auditwheel",
                "skip",
                "--manifest-path",
            ])
            .arg(repo_root().join("crates/stereogen-py/Cargo.toml"))
            .arg("--interpreter")
            .arg(venv.join("bin/python"))
            .arg("--out")
            .arg(wheels.path())
            .env("CARGO_TARGET_DIR", target_dir().join("python-ext"))
            // tests/run's test runner sets it for libtest; pyo3's and proc-macro2's build
            // scripts would see a nightly compiler and rebuild differently.
            .env_remove("RUSTC_BOOTSTRAP"),
        "maturin build",
    );
    let wheel = std::fs::read_dir(wheels.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "whl"))
        .expect("maturin wrote a wheel");
    pinned_venv::run(
        pinned_venv::pip_install(venv)
            .args(["--no-deps", "--force-reinstall"])
            .arg(&wheel),
        "pip install wheel",
    );
    installed.insert(venv.to_path_buf());
}

/// The base venvs: PyTorch's, and the one with `datasets`, `webdataset` and maturin on it.
pub fn base_venvs() -> (PathBuf, PathBuf) {
    let torch = pinned_venv::ensure_venv("venv-torch", TORCH_PINS);
    let hub = pinned_venv::ensure_venv_on(&torch, "venv-hub-on-torch", HUB_PINS);
    (torch, hub)
}

/// The directory of a venv's own packages.
pub fn site_packages(venv: &Path) -> PathBuf {
    let code = "import sysconfig; print(sysconfig.get_paths()['purelib'])";
    let out = pinned_venv::run(
        Command::new(venv.join("bin/python")).args(["-c", code]),
        "python -c sysconfig",
    );
    PathBuf::from(out.trim())
}

/// A venv made anew at `dir` (whatever was there is removed), seeing the packages of the venvs
/// `on` (a `.pth` file naming their site-packages, in that order) and nothing else. The same
/// path every run keeps the interpreter's path stable, so maturin's builds stay incremental.
pub fn fresh_venv(dir: &Path, on: &[&Path]) -> PathBuf {
    let _ = std::fs::remove_dir_all(dir);
    let python = std::env::var("STEREOGEN_BOOTSTRAP_PYTHON").unwrap_or_else(|_| "python3".into());
    pinned_venv::run(
        Command::new(python).args(["-m", "venv"]).arg(dir),
        "python3 -m venv",
    );
    if !on.is_empty() {
        let lines: String = on
            .iter()
            .map(|v| format!("{}\n", site_packages(v).display()))
            .collect();
        std::fs::write(site_packages(dir).join("base-venvs.pth"), lines).unwrap();
    }
    dir.to_path_buf()
}

pub use pinned_venv::python_home;

/// The target directory of this build (`<target>/<profile>/deps/<test>` or
/// `<target>/<profile>/examples/<example>` → `<target>`).
pub fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.ancestors()
        .nth(3)
        .expect("<target>/<profile>/deps/<test>")
        .to_path_buf()
}

/// The repository's root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}
