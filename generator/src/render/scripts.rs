//! The Blender-side Python ships inside the binary, so an installed `stereogen` needs no source
//! tree. It is written once per content hash under `$STEREOGEN_HOME/scripts/`.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

const SCRIPTS: &[(&str, &str)] = &[
    (
        "worker.py",
        include_str!("../../../blender_scripts/worker.py"),
    ),
    (
        "scene_builder.py",
        include_str!("../../../blender_scripts/scene_builder.py"),
    ),
    (
        "materials.py",
        include_str!("../../../blender_scripts/materials.py"),
    ),
    (
        "geometry.py",
        include_str!("../../../blender_scripts/geometry.py"),
    ),
    (
        "render_views.py",
        include_str!("../../../blender_scripts/render_views.py"),
    ),
    (
        "export_geometry.py",
        include_str!("../../../blender_scripts/export_geometry.py"),
    ),
];

fn content_hash() -> String {
    let mut h = Sha256::new();
    for (name, text) in SCRIPTS {
        h.update(name.as_bytes());
        h.update(text.as_bytes());
    }
    h.finalize()
        .iter()
        .take(8)
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Writes the scripts (if not already there) and returns the path of `worker.py`.
pub fn install_scripts(home: &Path) -> std::io::Result<PathBuf> {
    let dir = home.join("scripts").join(content_hash());
    if !dir.join("worker.py").is_file() {
        std::fs::create_dir_all(home.join("scripts"))?;
        let tmp = tempfile::Builder::new()
            .prefix(".scripts-")
            .tempdir_in(home.join("scripts"))?;
        for (name, text) in SCRIPTS {
            stereo_io::write_bytes_atomically(&tmp.path().join(name), text.as_bytes())
                .map_err(std::io::Error::other)?;
        }
        let tmp = tmp.keep();
        // Another process may have won the race; its copy is identical.
        if std::fs::rename(&tmp, &dir).is_err() {
            let _ = std::fs::remove_dir_all(&tmp);
        }
    }
    Ok(dir.join("worker.py"))
}
