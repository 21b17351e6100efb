//! ShapeNetCore (v1 and v2 layouts) and plain mesh folders.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, bail};
use serde::Deserialize;
use stereogen_plan::assets::SkippedAsset;
use walkdir::WalkDir;

use super::cache::{cached, tree_stamp};
use super::folder::{check_root, folder_key, index_files};

pub use stereogen_plan::assets::MeshAsset;

/// Mesh formats the worker imports (OFF and other trimesh formats go through trimesh).
pub const MESH_EXTENSIONS: &[&str] = &["obj", "glb", "gltf", "ply", "stl", "off"];

fn has_mesh_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| MESH_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Synset id → first name, from ShapeNet's `taxonomy.json` if present.
fn taxonomy(root: &Path) -> BTreeMap<String, String> {
    #[derive(Deserialize)]
    struct Entry {
        #[serde(rename = "synsetId")]
        synset_id: String,
        name: String,
    }
    let Ok(text) = std::fs::read_to_string(root.join("taxonomy.json")) else {
        return BTreeMap::new();
    };
    let Ok(entries) = serde_json::from_str::<Vec<Entry>>(&text) else {
        tracing::warn!(
            "{}: not a ShapeNet taxonomy; synset names unavailable",
            root.join("taxonomy.json").display()
        );
        return BTreeMap::new();
    };
    entries
        .into_iter()
        .map(|e| {
            (
                e.synset_id,
                e.name
                    .split(',')
                    .next()
                    .unwrap_or_default()
                    .trim()
                    .to_string(),
            )
        })
        .collect()
}

/// Indexes `<synset>/<model>/model.obj` (v1) and `<synset>/<model>/models/model_normalized.obj` (v2).
pub fn index_shapenet(
    root: &Path,
    synsets: &[String],
    home: &Path,
) -> anyhow::Result<(Vec<MeshAsset>, Vec<SkippedAsset>)> {
    check_root(root, "ShapeNet")?;
    let key = format!("{}|{}", folder_key(root), synsets.join(","));
    let (found, skipped): (Vec<MeshAsset>, Vec<SkippedAsset>) = cached(
        home,
        "shapenet",
        &key,
        &tree_stamp(root),
        || {
            let names = taxonomy(root);
            let mut found = Vec::new();
            let mut skipped = Vec::new();
            for entry in WalkDir::new(root)
                .follow_links(true)
                .min_depth(3)
                .max_depth(4)
                .sort_by_file_name()
            {
                let entry = entry.with_context(|| format!("cannot walk {}", root.display()))?;
                let rel = entry.path().strip_prefix(root).unwrap_or(entry.path());
                let parts: Vec<String> = rel
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect();
                let is_model = matches!(parts.as_slice(), [_, _, f] if f == "model.obj")
                    || matches!(parts.as_slice(), [_, _, d, f] if d == "models" && f == "model_normalized.obj");
                if !is_model {
                    continue;
                }
                let synset = parts[0].clone();
                if !synsets.is_empty() && !synsets.contains(&synset) {
                    continue;
                }
                if skipped_as_empty(&entry, &mut skipped) {
                    continue;
                }
                found.push(MeshAsset {
                    path: entry.path().to_path_buf(),
                    label: names.get(&synset).cloned(),
                    synset: Some(synset),
                });
            }
            Ok((found, skipped))
        },
    )?;
    if found.is_empty() {
        let filter = if synsets.is_empty() {
            String::new()
        } else {
            format!(" for synsets {}", synsets.join(", "))
        };
        bail!(
            "ShapeNet folder {} holds no <synset>/<model>/model.obj or .../models/model_normalized.obj{filter}",
            root.display()
        );
    }
    Ok((found, skipped))
}

/// A GLB must have a sound header, and a file that `assets fetch` recorded (`<stem>.json` with a
/// `sha256`) must still have the recorded bytes.
fn check_fetched(path: &Path) -> Result<(), String> {
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"))
    {
        return Ok(());
    }
    crate::objaverse::check_glb(path)?;
    let Ok(text) = std::fs::read_to_string(path.with_extension("json")) else {
        return Ok(());
    };
    let Ok(record) = serde_json::from_str::<crate::objaverse::ObjectRecord>(&text) else {
        return Ok(());
    };
    let sha = stereo_io::digest::sha256_file(path).map_err(|e| format!("cannot read it: {e}"))?;
    if sha != record.sha256 {
        return Err(format!(
            "corrupt: SHA-256 {sha} is not the {} its record states",
            record.sha256
        ));
    }
    Ok(())
}

/// An OBJ must be text with at least one vertex, every vertex three finite numbers: a file of
/// other bytes imports as nothing and a NaN vertex poisons the object's bounds, so both are
/// refused here (listed in `skipped_assets.jsonl`) rather than left to be drawn.
fn check_obj(path: &Path) -> Result<(), String> {
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"))
    {
        return Ok(());
    }
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read it: {e}"))?;
    let text = std::str::from_utf8(&bytes).map_err(|_| "not an OBJ: not text".to_string())?;
    let mut vertices = 0;
    for (number, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        vertices += 1;
        let xyz: Vec<f64> = words.take(3).filter_map(|w| w.parse().ok()).collect();
        if xyz.len() < 3 || !xyz.iter().all(|c| c.is_finite()) {
            return Err(format!(
                "not a usable OBJ: the vertex on line {} is not three finite numbers",
                number + 1
            ));
        }
    }
    if vertices == 0 {
        return Err("not a usable OBJ: no vertices".into());
    }
    Ok(())
}

/// Indexes every mesh file under `root`.
pub fn index_mesh_folder(
    root: &Path,
    home: &Path,
) -> anyhow::Result<(Vec<MeshAsset>, Vec<SkippedAsset>)> {
    // "meshes-obj-checked": indexes cached before OBJ files were checked are not reused.
    let (found, skipped) = index_files(root, home, "mesh", "meshes-obj-checked", |entry| {
        let path = entry.path();
        if !entry.file_type().is_file() || !has_mesh_extension(path) {
            return None;
        }
        let usable = check_not_empty(entry)
            .and_then(|()| check_fetched(path))
            .and_then(|()| check_obj(path));
        Some(usable.map(|()| MeshAsset {
            path: path.to_path_buf(),
            synset: None,
            label: None,
        }))
    })?;
    if found.is_empty() {
        bail!(
            "mesh folder {} holds no {} files",
            root.display(),
            MESH_EXTENSIONS.join("/")
        );
    }
    Ok((found, skipped))
}

/// Whether `entry` is an empty file (or one whose size cannot be read), which is then listed
/// in `skipped` instead of being indexed: Blender would fail on it at render time.
fn skipped_as_empty(entry: &walkdir::DirEntry, skipped: &mut Vec<SkippedAsset>) -> bool {
    let Err(reason) = check_not_empty(entry) else {
        return false;
    };
    skipped.push(SkippedAsset {
        path: entry.path().to_path_buf(),
        reason,
    });
    true
}

/// An empty file (or one whose size cannot be read) is refused: Blender would fail on it.
fn check_not_empty(entry: &walkdir::DirEntry) -> Result<(), String> {
    match entry.metadata().map(|m| m.len()).unwrap_or(0) {
        0 => Err("empty file".into()),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_shapenet_layouts_are_found_and_empty_files_skipped() {
        let root = tempfile::tempdir().unwrap();
        let home = tempfile::tempdir().unwrap();
        let v1 = root.path().join("03001627/aaa");
        let v2 = root.path().join("04379243/bbb/models");
        let empty = root.path().join("04379243/ccc/models");
        for d in [&v1, &v2, &empty] {
            std::fs::create_dir_all(d).unwrap();
        }
        std::fs::write(v1.join("model.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        std::fs::write(
            v2.join("model_normalized.obj"),
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        )
        .unwrap();
        std::fs::write(empty.join("model_normalized.obj"), "").unwrap();
        std::fs::write(
            root.path().join("taxonomy.json"),
            r#"[{"synsetId":"03001627","name":"chair,seat","children":[],"numInstances":1}]"#,
        )
        .unwrap();
        let (found, skipped) = index_shapenet(root.path(), &[], home.path()).unwrap();
        assert_eq!(found.len(), 2);
        assert_eq!(found[0].label.as_deref(), Some("chair"));
        assert_eq!(skipped.len(), 1);
        let (only, _) = index_shapenet(root.path(), &["04379243".into()], home.path()).unwrap();
        assert_eq!(only.len(), 1);
        // Cached, then invalidated by a new model.
        let extra = root.path().join("03001627/ddd");
        std::fs::create_dir_all(&extra).unwrap();
        std::fs::write(extra.join("model.obj"), "v 0 0 0\n").unwrap();
        assert_eq!(
            index_shapenet(root.path(), &[], home.path())
                .unwrap()
                .0
                .len(),
            3
        );
    }

    #[test]
    fn broken_objs_in_a_mesh_folder_are_skipped_with_the_reason() {
        let root = tempfile::tempdir().unwrap();
        let home = tempfile::tempdir().unwrap();
        let tetra = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n";
        std::fs::write(root.path().join("good.obj"), tetra).unwrap();
        std::fs::write(
            root.path().join("nan.obj"),
            tetra.replace("v 1 0 0", "v nan 0 0"),
        )
        .unwrap();
        std::fs::write(
            root.path().join("noise.obj"),
            [0xff_u8, 0xfe, 0x00, 0x81, 0x13, 0x37],
        )
        .unwrap();
        std::fs::write(root.path().join("faces_only.obj"), "f 1 2 3\n").unwrap();
        let (found, skipped) = index_mesh_folder(root.path(), home.path()).unwrap();
        assert_eq!(
            found
                .iter()
                .map(|m| m.path.file_name().unwrap())
                .collect::<Vec<_>>(),
            ["good.obj"]
        );
        let reasons: BTreeMap<String, String> = skipped
            .iter()
            .map(|s| {
                (
                    s.path.file_name().unwrap().to_string_lossy().into_owned(),
                    s.reason.clone(),
                )
            })
            .collect();
        assert!(
            reasons["nan.obj"].contains("line 2 is not three finite numbers"),
            "{reasons:?}"
        );
        assert!(reasons["noise.obj"].contains("not text"), "{reasons:?}");
        assert!(
            reasons["faces_only.obj"].contains("no vertices"),
            "{reasons:?}"
        );
    }

    #[test]
    fn missing_folder_is_a_clear_error() {
        let home = tempfile::tempdir().unwrap();
        let err = index_mesh_folder(Path::new("/no/such/meshes"), home.path())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("/no/such/meshes") && err.contains("does not exist"),
            "{err}"
        );
    }
}
