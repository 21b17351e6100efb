//! Installing the pack: `pip download` fetches the pinned wheels (no dependencies, binary wheels
//! for the interpreter that runs pip), and only the pack's files are taken out of them. Nothing
//! of the packages is imported or installed, so their own dependencies do not matter.
//!
//! The pack is built under a temporary name and renamed into place with its index written last;
//! a lock makes concurrent installers wait for one another.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, bail};
use fs4::fs_std::FileExt;

use super::{
    FILES, PACKAGES, PackIndex, index_file, index_pack, pack_dir, pack_name, requirements, site_dir,
};

/// The wheel of `package` in `dir` (`<name>-<version>-*.whl`, the name normalised as wheels
/// spell it).
fn find_wheel(dir: &Path, name: &str, version: &str) -> Option<PathBuf> {
    let prefix = format!("{}-{version}-", name.replace('-', "_").to_ascii_lowercase());
    std::fs::read_dir(dir)
        .ok()?
        .flatten()
        .map(|e| e.path())
        .find(|p| {
            let file = p
                .file_name()
                .map(|f| f.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default();
            file.starts_with(&prefix) && file.ends_with(".whl")
        })
}

/// Takes the pack's files of package `package` out of its wheel into `site`. Files the wheel
/// lacks are left out (the index reports them as missing).
fn extract(wheel: &Path, package: usize, site: &Path) -> anyhow::Result<usize> {
    let file =
        std::fs::File::open(wheel).with_context(|| format!("cannot open {}", wheel.display()))?;
    let mut archive = zip::ZipArchive::new(file)
        .with_context(|| format!("{}: not a wheel (zip) file", wheel.display()))?;
    let mut n = 0;
    for f in FILES.iter().filter(|f| f.package == package) {
        let Ok(mut entry) = archive.by_name(f.path) else {
            tracing::warn!("{} has no {}", wheel.display(), f.path);
            continue;
        };
        let mut bytes = Vec::with_capacity(entry.size() as usize);
        entry
            .read_to_end(&mut bytes)
            .with_context(|| format!("{}: cannot read {}", wheel.display(), f.path))?;
        let dest = site.join(f.path);
        std::fs::create_dir_all(dest.parent().expect("pack paths have a folder"))
            .with_context(|| format!("cannot create the folder of {}", dest.display()))?;
        std::fs::write(&dest, &bytes)
            .with_context(|| format!("cannot write {}", dest.display()))?;
        n += 1;
    }
    Ok(n)
}

fn download_wheels(python: &Path, dest: &Path) -> anyhow::Result<()> {
    let status = Command::new(python)
        .args([
            "-m",
            "pip",
            "download",
            "--no-deps",
            "--only-binary=:all:",
            "--disable-pip-version-check",
            "--no-input",
            "--progress-bar",
            "on",
            "-d",
        ])
        .arg(dest)
        .args(requirements())
        // pip's report goes to stderr: commands such as `plan` print their result on stdout.
        .stdout(std::io::stderr())
        .stderr(Stdio::inherit())
        .status()
        .with_context(|| format!("cannot run {} -m pip", python.display()))?;
    if !status.success() {
        bail!(
            "`pip download {}` exited with {status}; nothing was installed, fix the cause and run `stereogen setup` again",
            requirements().join(" ")
        );
    }
    Ok(())
}

/// Installs the pack under `home` with `python`'s pip (any Python with pip; setup uses the
/// managed Blender environment's), unless it is there already. Returns its index.
pub fn install_pack(home: &Path, python: &Path) -> anyhow::Result<PackIndex> {
    let content = home.join("content");
    std::fs::create_dir_all(&content)
        .with_context(|| format!("cannot create {}", content.display()))?;
    let lock_path = content.join(".install.lock");
    let lock = std::fs::File::create(&lock_path)
        .with_context(|| format!("cannot create {}", lock_path.display()))?;
    lock.lock_exclusive()
        .with_context(|| format!("cannot lock {}", lock_path.display()))?;

    let dir = pack_dir(home);
    if index_file(&dir).is_file() {
        return Ok(index_pack(&dir, &[]));
    }
    // A folder without an index is an install that was killed before it finished.
    let _ = std::fs::remove_dir_all(&dir);
    let tmp = content.join(format!(".{}.tmp-{}", pack_name(), std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let result = (|| {
        let wheels = tmp.join("wheels");
        std::fs::create_dir_all(&wheels)
            .with_context(|| format!("cannot create {}", wheels.display()))?;
        eprintln!(
            "stereogen: downloading the content pack ({}) ...",
            requirements().join(", ")
        );
        download_wheels(python, &wheels)?;
        for (i, p) in PACKAGES.iter().enumerate() {
            let wheel = find_wheel(&wheels, p.name, p.version).with_context(|| {
                format!(
                    "pip downloaded no wheel of {}=={} into {}",
                    p.name,
                    p.version,
                    wheels.display()
                )
            })?;
            extract(&wheel, i, &site_dir(&tmp))?;
        }
        std::fs::remove_dir_all(&wheels)
            .with_context(|| format!("cannot remove {}", wheels.display()))?;
        std::fs::rename(&tmp, &dir)
            .with_context(|| format!("cannot move the pack into {}", dir.display()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result?;
    let index = index_pack(&dir, &[]);
    let json = serde_json::to_string_pretty(&index).expect("the index serialises");
    stereo_io::write_bytes_atomically(&index_file(&dir), json.as_bytes())?;
    Ok(index)
}

/// A Python whose pip can download the pack when nothing else is given: `$STEREOGEN_PYTHON`,
/// the managed Blender environment's (it has pip), then `python3` on PATH.
pub fn default_pip_python(home: &Path) -> PathBuf {
    if let Some(p) = std::env::var_os("STEREOGEN_PYTHON").filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    crate::blender_env::installed_managed_python(home).unwrap_or_else(|| PathBuf::from("python3"))
}

/// The installed pack's folder, installing it first (as the first `generate` installs Blender)
/// when it is missing.
pub fn ensure_installed(home: &Path) -> anyhow::Result<PathBuf> {
    let dir = pack_dir(home);
    if !index_file(&dir).is_file() {
        install_pack(home, &default_pip_python(home)).context("the recipe uses the built-in content pack (sources.builtin_pack), which is not installed; `stereogen setup` installs it, or set sources.builtin_pack = false")?;
    }
    Ok(dir)
}

/// The index of the installed pack (re-verified: files may have changed since setup).
pub fn installed_index(home: &Path, exclude_licences: &[String]) -> anyhow::Result<PackIndex> {
    let dir = pack_dir(home);
    if !index_file(&dir).is_file() {
        bail!(
            "the built-in content pack is not installed in {}; run `stereogen setup`",
            dir.display()
        );
    }
    Ok(index_pack(&dir, exclude_licences))
}
