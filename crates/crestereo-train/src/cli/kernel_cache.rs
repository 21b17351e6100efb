//! CubeCL's on-disk kernel caches for the GPU devices. CubeCL compiles every kernel at first use
//! (CUDA C++ through NVRTC, or SPIR-V for Vulkan) and autotunes matrix products and convolutions
//! by compiling and timing every candidate. Without a cache that is paid again by every process:
//! on an NVIDIA H200 a first `crestereo infer --device cuda` (two-pass, 128×192) compiled 115
//! kernels in 165 s and had not finished. CubeCL keeps compiled kernels on disk only when asked
//! (`compilation.cache`), and its autotune results in the `target/` folder of the working
//! directory's Cargo project (or the user cache folder outside one).
//!
//! Layout, under the parent folder (`CRESTEREO_KERNEL_CACHE`, default
//! `$XDG_CACHE_HOME/stereogen/kernels`, else `~/.cache/stereogen/kernels`):
//!
//! ```text
//! <version>-<content hash of the binary>/   one build of `crestereo`
//!     sm_90/ …   CubeCL's compiled kernels (PTX) and autotune results for one CUDA architecture
//!     spirv/     the same for Vulkan (SPIR-V is not tied to one GPU)
//!     cuda-jit/  NVIDIA's own cache of machine code made from the PTX (CUDA_CACHE_PATH)
//!     */census/  what each accounted run compiled (`crestereo warmup`, CRESTEREO_KERNEL_CENSUS)
//! binaries/      the hash of each copy of a binary seen, under its size, time and inode
//! ```
//!
//! The build folder is named after a hash of the executable's bytes, not its size and time: a
//! kernel's cache key is its id, not its source, so a rebuilt binary with a changed kernel body
//! must not find the old one, while a *copy* of the same binary (a cluster image, another node's
//! install, a job's scratch copy) must find the kernels its twin compiled. PTX is compiled for
//! one architecture (`--gpu-architecture=sm_XX`), so each architecture has its own folder: a
//! folder shared by H100 and A100 nodes serves both. NVIDIA's driver turns the PTX into machine
//! code at load time and keeps that in `CUDA_CACHE_PATH` (by default a 256 MiB folder in the
//! user's home); it is pointed into the same build folder (unless already set) so that one
//! `crestereo warmup` on one node fills everything a later job on any node needs.
//!
//! A `cubecl.toml` / `burn.toml` in the working directory or above leaves CubeCL's configuration
//! to that file; `CRESTEREO_KERNEL_CACHE=off` turns the caches off.

use std::path::{Path, PathBuf};

use cubecl_common::config::RuntimeConfig;
use cubecl_runtime::config::CubeClRuntimeConfig;
use cubecl_runtime::config::autotune::AutotuneLevel;
use cubecl_runtime::config::cache::CacheConfig;

/// Build folders kept beside the current one (the newest first); older ones are removed.
const KEEP_BUILDS: usize = 3;

/// The GPU a command will run on, as far as the cache layout needs to know it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GpuTarget {
    /// CUDA device `ordinal` (its architecture names the kernel folder).
    Cuda { ordinal: usize },
    /// wgpu with SPIR-V kernels.
    Vulkan,
}

/// Sets CubeCL's configuration before any GPU use; returns the folder CubeCL's compiled kernels
/// and autotune results go to (`<parent>/<version>-<hash>/<arch>`), or `None` when the caches
/// stay off or a CubeCL config file decides. `census` turns on the compilation log
/// [`super::kernel_census`] reads (it needs no cache folder). Must run before the first backend
/// call, and while this is the only thread (it may set `CUDA_CACHE_PATH`).
pub fn configure(target: GpuTarget, census: bool) -> Option<PathBuf> {
    if config_file_above_cwd() {
        if census {
            tracing::warn!(
                "a cubecl.toml or burn.toml above the working folder decides CubeCL's settings: no kernel census"
            );
        }
        return None;
    }
    let folder = device_folder_of_this_build(target);
    if folder.is_none() && !census {
        return None;
    }
    let mut config = CubeClRuntimeConfig::from_current_dir().override_from_env();
    if let Some(f) = &folder {
        config.compilation.cache = Some(CacheConfig::File(f.clone()));
        config.autotune.cache = CacheConfig::File(f.clone());
    }
    if let Some(level) = autotune_level() {
        config.autotune.level = level;
    }
    if census {
        super::kernel_census::configure(&mut config);
    }
    CubeClRuntimeConfig::set(config);
    folder
}

/// Makes (and prunes around) this build's folder for `target`'s kernels; `None` when the caches
/// are off or the folder cannot be made.
fn device_folder_of_this_build(target: GpuTarget) -> Option<PathBuf> {
    let setting = std::env::var_os("CRESTEREO_KERNEL_CACHE");
    if setting.as_deref().is_some_and(|s| s == "off") {
        return None;
    }
    let parent = setting.map(PathBuf::from).or_else(default_parent)?;
    let build = parent.join(build_id(&parent)?);
    if target != GpuTarget::Vulkan && std::env::var_os("CUDA_CACHE_PATH").is_none() {
        // SAFETY: start-up, before any other thread exists (see `configure`); read by the CUDA
        // driver when it initialises, below or at the first kernel.
        unsafe {
            std::env::set_var("CUDA_CACHE_PATH", build.join("cuda-jit"));
            // The driver's default limit (256 MiB) holds a fraction of a training run's kernels.
            if std::env::var_os("CUDA_CACHE_MAXSIZE").is_none() {
                std::env::set_var("CUDA_CACHE_MAXSIZE", "4294967296");
            }
        }
    }
    let device = build.join(architecture_folder(target));
    if let Err(e) = std::fs::create_dir_all(&device) {
        tracing::warn!(
            "kernel cache {} not usable ({e}); kernels compile every run",
            device.display()
        );
        return None;
    }
    prune_old_builds(&parent, &build);
    Some(device)
}

/// `sm_<major><minor>` of a CUDA device (`cuda` when the driver cannot say), `spirv` for Vulkan.
fn architecture_folder(target: GpuTarget) -> String {
    match target {
        GpuTarget::Vulkan => "spirv".into(),
        GpuTarget::Cuda { ordinal } => cuda_architecture(ordinal)
            .map(|(major, minor)| format!("sm_{major}{minor}"))
            .unwrap_or_else(|| "cuda".into()),
    }
}

/// The compute capability of CUDA device `ordinal`, asked of the driver (the same numbers
/// CubeCL compiles for).
#[cfg(feature = "cuda")]
fn cuda_architecture(ordinal: usize) -> Option<(i32, i32)> {
    use cudarc::driver::result;
    use cudarc::driver::sys::CUdevice_attribute::{
        CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MAJOR, CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MINOR,
    };
    result::init().ok()?;
    let device = result::device::get(i32::try_from(ordinal).ok()?).ok()?;
    // SAFETY: `device` is a valid device handle from `cuDeviceGet`; the attributes are
    // read-only properties.
    unsafe {
        let major =
            result::device::get_attribute(device, CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MAJOR)
                .ok()?;
        let minor =
            result::device::get_attribute(device, CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MINOR)
                .ok()?;
        Some((major, minor))
    }
}

#[cfg(not(feature = "cuda"))]
fn cuda_architecture(_ordinal: usize) -> Option<(i32, i32)> {
    None
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

/// `<version>-<hash>` of the running executable: the first 16 hex digits of the SHA-256 of its
/// bytes, so that a rebuilt binary gets a new folder and a copied one finds its twin's. Hashing
/// a release binary with debug information (~400 MB) takes about a second, so the hash is kept
/// in `<parent>/binaries/` under the file's size, modification time (ns) and inode: each copy
/// of a binary is hashed once, its later starts read the hash back.
fn build_id(parent: &Path) -> Option<String> {
    let exe = std::env::current_exe().ok()?;
    let memo = memo_path(parent, &exe);
    if let Some(hash) = memo
        .as_deref()
        .and_then(|m| std::fs::read_to_string(m).ok())
        .filter(|h| h.len() == 16 && h.bytes().all(|b| b.is_ascii_hexdigit()))
    {
        return Some(format!("{}-{hash}", env!("CARGO_PKG_VERSION")));
    }
    match content_hash(&exe) {
        Ok(hash) => {
            if let Some(m) = memo {
                // Best effort: a read-only shared folder only costs the hash next time.
                let _ = std::fs::create_dir_all(parent.join("binaries"))
                    .and_then(|()| std::fs::write(&m, &hash));
            }
            Some(format!("{}-{hash}", env!("CARGO_PKG_VERSION")))
        }
        Err(e) => {
            tracing::warn!(
                "cannot read {} to name its kernel cache ({e}); kernels compile every run",
                exe.display()
            );
            None
        }
    }
}

/// `<parent>/binaries/<size>-<mtime ns>-<inode>`: where the hash of this copy of the binary is
/// kept.
fn memo_path(parent: &Path, exe: &Path) -> Option<PathBuf> {
    use std::os::unix::fs::MetadataExt;
    let meta = std::fs::metadata(exe).ok()?;
    let key = format!(
        "{}-{}{:09}-{}",
        meta.len(),
        meta.mtime(),
        meta.mtime_nsec(),
        meta.ino()
    );
    Some(parent.join("binaries").join(key))
}

/// The first 16 hex digits of the SHA-256 of the file at `path`.
fn content_hash(path: &Path) -> std::io::Result<String> {
    use sha2::{Digest, Sha256};
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    let digest = hasher.finalize();
    Ok(digest[..8].iter().map(|b| format!("{b:02x}")).collect())
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
        .filter(|e| e.path() != current && e.path().is_dir() && e.file_name() != "binaries")
        .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
        .collect();
    builds.sort_by_key(|b| std::cmp::Reverse(b.0));
    for (_, old) in builds.into_iter().skip(KEEP_BUILDS) {
        let _ = std::fs::remove_dir_all(old);
    }
}
