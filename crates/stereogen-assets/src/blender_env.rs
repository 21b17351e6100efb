//! Where the managed Blender environment lives: `$STEREOGEN_HOME/blender/bpy-<version>-...`, a
//! virtual environment with the pinned `bpy` wheel (and pip). The one owner of that location:
//! the generator's runtime installs and runs it, the content pack borrows its pip.

use std::path::{Path, PathBuf};

/// The `bpy` wheel the managed environment pins (Blender 4.5 LTS).
pub const BPY_VERSION: &str = "4.5.15";
/// trimesh loads the mesh formats Blender has no importer for (OFF and others).
pub const TRIMESH_VERSION: &str = "4.12.2";

/// The folder that holds managed environments, current and older.
pub fn managed_envs_root(home: &Path) -> PathBuf {
    home.join("blender")
}

/// The current managed environment's folder. Its name changes with the pinned versions, so an
/// upgrade installs afresh.
pub fn managed_env_dir(home: &Path) -> PathBuf {
    managed_envs_root(home).join(format!("bpy-{BPY_VERSION}-trimesh-{TRIMESH_VERSION}"))
}

/// The interpreter of the current managed environment (it may not exist yet).
pub fn managed_python(home: &Path) -> PathBuf {
    managed_env_dir(home).join("bin").join("python")
}

/// An installed managed interpreter: the current environment's, else the newest-named older one
/// (any of them has pip); `None` when none is installed.
pub fn installed_managed_python(home: &Path) -> Option<PathBuf> {
    let current = managed_python(home);
    if current.is_file() {
        return Some(current);
    }
    std::fs::read_dir(managed_envs_root(home))
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path().join("bin").join("python"))
        .filter(|p| p.is_file())
        .max()
}
