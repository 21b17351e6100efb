//! CubeCL's on-disk kernel caches for the GPU devices. CubeCL compiles every kernel at first use
//! (CUDA C++ through NVRTC, or SPIR-V for Vulkan) and autotunes matrix products and convolutions
//! by compiling and timing every candidate. Without a cache that is paid again by every process:
//! on an NVIDIA H200 a first `crestereo infer --device cuda` (two-pass, 128×192) compiled 115
//! kernels in 165 s and had not finished. CubeCL keeps compiled kernels on disk only when asked
//! (`compilation.cache`), and its autotune results in the `target/` folder of the working
//! directory's Cargo project (or the user cache folder outside one).
//!
//! Both go to one folder per build of this binary: a kernel's cache key is its id, not its
//! source, so a rebuilt binary with a changed kernel body must not find the old one. A
//! `cubecl.toml` / `burn.toml` in the working directory or above leaves CubeCL's configuration
//! to that file; `CRESTEREO_KERNEL_CACHE=off` turns the caches off, any other value names the
//! parent folder (default: `$XDG_CACHE_HOME/stereogen/kernels`, else `~/.cache/stereogen/kernels`).

use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use cubecl_common::config::RuntimeConfig;
use cubecl_runtime::config::CubeClRuntimeConfig;
use cubecl_runtime::config::autotune::AutotuneLevel;
use cubecl_runtime::config::cache::CacheConfig;

/// Build folders kept beside the current one (the newest first); older ones are removed.
const KEEP_BUILDS: usize = 3;

/// Sets CubeCL's configuration before any GPU use; returns the cache folder, or `None` when the
/// caches stay off or a CubeCL config file decides. Must run before the first backend call.
pub fn configure() -> Option<PathBuf> {
    let setting = std::env::var_os("CRESTEREO_KERNEL_CACHE");
    if setting.as_deref().is_some_and(|s| s == "off") || config_file_above_cwd() {
        return None;
    }
    let parent = setting.map(PathBuf::from).or_else(default_parent)?;
    let dir = parent.join(build_id()?);
    if let Err(e) = std::fs::create_dir_all(&dir) {
        tracing::warn!(
            "kernel cache {} not usable ({e}); kernels compile every run",
            dir.display()
        );
        return None;
    }
    prune_old_builds(&parent, &dir);
    let mut config = CubeClRuntimeConfig::from_current_dir().override_from_env();
    config.compilation.cache = Some(CacheConfig::File(dir.clone()));
    config.autotune.cache = CacheConfig::File(dir.clone());
    if let Some(level) = autotune_level() {
        config.autotune.level = level;
    }
    CubeClRuntimeConfig::set(config);
    Some(dir)
}

/// `CRESTEREO_AUTOTUNE_LEVEL`: minimal, balanced (CubeCL's default), extensive or full.
/// `crestereo warmup --autotune-level` sets it; the commands that use a warmed cache must see
/// the same level to find its results.
fn autotune_level() -> Option<AutotuneLevel> {
    let value = std::env::var("CRESTEREO_AUTOTUNE_LEVEL").ok()?;
    match parse_autotune_level(&value) {
        Ok(level) => Some(level),
        Err(e) => {
            tracing::warn!("{e}; CubeCL's default level is used");
            None
        }
    }
}

pub fn parse_autotune_level(value: &str) -> Result<AutotuneLevel, String> {
    match value.trim().to_ascii_lowercase().as_str() {
        "minimal" => Ok(AutotuneLevel::Minimal),
        "balanced" => Ok(AutotuneLevel::Balanced),
        "extensive" => Ok(AutotuneLevel::Extensive),
        "full" => Ok(AutotuneLevel::Full),
        other => Err(format!(
            "autotune level `{other}` is not minimal, balanced, extensive or full"
        )),
    }
}

fn default_parent() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
    Some(base.join("stereogen").join("kernels"))
}

/// `<version>-<size>-<mtime>` of the running executable: a new build gets a new folder.
fn build_id() -> Option<String> {
    let meta = std::fs::metadata(std::env::current_exe().ok()?).ok()?;
    let mtime = meta.modified().ok()?.duration_since(UNIX_EPOCH).ok()?;
    Some(format!(
        "{}-{}-{}",
        env!("CARGO_PKG_VERSION"),
        meta.len(),
        mtime.as_secs()
    ))
}

fn config_file_above_cwd() -> bool {
    let Ok(mut dir) = std::env::current_dir() else {
        return false;
    };
    loop {
        if ["cubecl.toml", "CubeCL.toml", "burn.toml", "Burn.toml"]
            .iter()
            .any(|n| dir.join(n).is_file())
        {
            return true;
        }
        if !dir.pop() {
            return false;
        }
    }
}

/// Removes build folders beyond the newest [`KEEP_BUILDS`] (never `current`); best effort.
fn prune_old_builds(parent: &Path, current: &Path) {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    let mut builds: Vec<(std::time::SystemTime, PathBuf)> = entries
        .filter_map(|e| e.ok())
        .filter(|e| e.path() != current && e.path().is_dir())
        .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
        .collect();
    builds.sort_by_key(|b| std::cmp::Reverse(b.0));
    for (_, old) in builds.into_iter().skip(KEEP_BUILDS) {
        let _ = std::fs::remove_dir_all(old);
    }
}
