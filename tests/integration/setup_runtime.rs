//! `stereogen setup` failures: a clear line, and nothing half-installed left behind.

use std::path::Path;
use std::process::Command;

use test_support::stereogen_cmd;

fn setup(home: &Path) -> Command {
    let mut c = stereogen_cmd(["setup"]);
    c.env("STEREOGEN_HOME", home)
        .env_remove("STEREOGEN_PYTHON")
        .env_remove("STEREOGEN_BOOTSTRAP_PYTHON");
    c
}

fn leftovers(home: &Path) -> Vec<String> {
    std::fs::read_dir(home.join("blender"))
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n != ".setup.lock")
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn wrong_bootstrap_python_is_explained() {
    let home = tempfile::tempdir().unwrap();
    let fake = home.path().join("python3.12");
    std::fs::write(&fake, "#!/bin/sh\necho 3.12.4\n").unwrap();
    std::fs::set_permissions(&fake, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let out = setup(home.path())
        .env("STEREOGEN_BOOTSTRAP_PYTHON", &fake)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("is Python 3.12.4") && err.contains("Python 3.11"),
        "{err}"
    );
    assert!(leftovers(home.path()).is_empty());

    let out = setup(home.path())
        .env("STEREOGEN_BOOTSTRAP_PYTHON", "/no/such/python3")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cannot run /no/such/python3"), "{err}");
}

#[test]
fn failed_pip_install_leaves_nothing_behind() {
    // A real venv and a real pip, pointed at an index on a closed loopback port.
    let home = tempfile::tempdir().unwrap();
    let out = setup(home.path())
        .env("PIP_INDEX_URL", "http://127.0.0.1:9/simple")
        .env("PIP_RETRIES", "0")
        .env("PIP_TIMEOUT", "2")
        .env("PIP_NO_CACHE_DIR", "1")
        .env("PIP_FIND_LINKS", "")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    let last = err.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("error: ")
            && last.contains("pip install bpy")
            && last.contains("nothing was installed"),
        "{err}"
    );
    assert!(
        leftovers(home.path()).is_empty(),
        "left behind: {:?}",
        leftovers(home.path())
    );
}
