//! A sample's scene file: the SceneSpec that reproduces it. Every reader and writer of the file
//! goes through here, so how it is stored on disk is decided in one place.
//!
//! **Storage.** New samples store the spec as compact JSON compressed with gzip
//! (`<id>.scene.json.gz`; `zcat X.scene.json.gz | jq` reads it). A tree scene's leaves and
//! branches are tens of thousands of full-precision floats (pretty JSON 2–3 MB); compact JSON in
//! gzip keeps every bit of them at about a fifth of that. Floats are the bulk and carry nearly
//! 8 bytes of entropy each, so a binary encoding would win little more; storing only the
//! planner's inputs would tie re-rendering to the asset folders as they were.
//!
//! **Reading** goes by the content, not the name: gzip's magic bytes, else plain JSON — so the
//! plain `<id>.scene.json` of datasets made before still reads, and so does a hand-written spec.

use std::io::Write;
use std::path::Path;

use anyhow::Context;
use flate2::Compression;
use flate2::read::GzDecoder;
use flate2::write::GzEncoder;

use stereo_io::limits::{MAX_DOCUMENT_BYTES, read_file_capped, read_to_end_capped};

use crate::plan::{BaseColor, SceneSpec, Shape, check_scene_spec};

/// The first two bytes of every gzip stream.
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// The bytes that go to disk for `spec`: gzip'd compact JSON when `path` ends in `.gz`, else the
/// spec's canonical (pretty) JSON. Equal specs give equal bytes (the gzip header carries no
/// name and no time).
pub fn encode_scene_spec(path: &Path, spec: &SceneSpec) -> Vec<u8> {
    if path.extension().is_some_and(|e| e == "gz") {
        let json = serde_json::to_vec(spec).expect("a SceneSpec always serialises");
        let mut gz = GzEncoder::new(Vec::with_capacity(json.len() / 4), Compression::default());
        gz.write_all(&json).expect("writing to memory cannot fail");
        gz.finish().expect("writing to memory cannot fail")
    } else {
        spec.to_json().into_bytes()
    }
}

/// Writes `spec` to `path` atomically, stored as its name says ([`encode_scene_spec`]).
/// Durable: the error names the path and the OS error.
pub fn write_scene_spec(path: &Path, spec: &SceneSpec) -> anyhow::Result<()> {
    Ok(stereo_io::write_bytes_atomically(
        path,
        &encode_scene_spec(path, spec),
    )?)
}

/// Reads the SceneSpec stored at `path` (gzip'd or plain JSON); the error names the file and the
/// problem.
/// The file and its decompressed JSON are each held to the limits policy's
/// [`MAX_DOCUMENT_BYTES`] (a tree scene is ~3 MB), so a gzip bomb stops at the limit.
pub fn read_scene_spec(path: &Path) -> anyhow::Result<SceneSpec> {
    let bytes = read_file_capped(path, MAX_DOCUMENT_BYTES, "a scene spec")?;
    decode_scene_spec(&bytes).with_context(|| format!("{}: not a SceneSpec", path.display()))
}

/// The spec in `bytes`, gzip'd or plain JSON.
pub fn decode_scene_spec(bytes: &[u8]) -> anyhow::Result<SceneSpec> {
    let text = if bytes.starts_with(&GZIP_MAGIC) {
        let json = read_to_end_capped(
            GzDecoder::new(bytes),
            Path::new("gzip data"),
            MAX_DOCUMENT_BYTES,
            "the decompressed spec",
        )
        .map_err(|e| match e.io_kind() {
            Some(_) => anyhow::anyhow!("damaged gzip data"),
            None => anyhow::anyhow!("{e}"),
        })?;
        String::from_utf8(json).context("gzip data that is not UTF-8 JSON")?
    } else {
        String::from_utf8(bytes.to_vec()).context("neither gzip nor UTF-8 JSON")?
    };
    Ok(SceneSpec::from_json(&text)?)
}

/// [`read_scene_spec`], then the plan's [`check_scene_spec`] and the files it names
/// ([`check_spec_files`]): a spec that is about to be rendered.
pub fn read_renderable_spec(path: &Path) -> anyhow::Result<SceneSpec> {
    let spec = read_scene_spec(path)?;
    check_scene_spec(&spec).with_context(|| format!("{}: cannot be rendered", path.display()))?;
    check_spec_files(&spec).with_context(|| format!("{}: cannot be rendered", path.display()))?;
    Ok(spec)
}

/// The files a spec hands to Blender: each mesh candidate and photo texture that exists must be a
/// regular file (a pipe or device would hang or flood the worker's importer) with an extension
/// the asset folders take, and a photo whose header can be read must be within the image limits
/// (a small PNG can claim 30000×30000 pixels, which Blender would decode whole). A missing file
/// is left to the worker, which skips a mesh candidate or paints a photo's fallback colour, as
/// for a planned spec whose assets moved.
pub fn check_spec_files(spec: &SceneSpec) -> anyhow::Result<()> {
    use crate::assets::{meshes::MESH_EXTENSIONS, textures::TEXTURE_EXTENSIONS};
    let check =
        |key: String, path: &Path, extensions: &[&str], photo: bool| -> anyhow::Result<()> {
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            if !ext.as_deref().is_some_and(|e| extensions.contains(&e)) {
                anyhow::bail!(
                    "key `{key}` is invalid: {} is not a {} file ({})",
                    path.display(),
                    if photo { "photo" } else { "mesh" },
                    extensions.join(", ")
                );
            }
            let Ok(meta) = std::fs::metadata(path) else {
                return Ok(());
            };
            if !meta.is_file() {
                anyhow::bail!(
                    "key `{key}` is invalid: {} is not a regular file (a folder, device or pipe)",
                    path.display()
                );
            }
            if photo && let Some((w, h)) = image_header_size(path) {
                stereo_io::limits::check_image_size(path, w.into(), h.into())
                    .with_context(|| format!("key `{key}` is invalid"))?;
            }
            Ok(())
        };
    for (i, o) in spec.objects.iter().enumerate() {
        if let Shape::MeshFile { candidates, .. } = &o.shape {
            for (j, p) in candidates.iter().enumerate() {
                let key = format!("objects[{i}].shape.candidates[{j}]");
                check(key, p, MESH_EXTENSIONS, false)?;
            }
        }
        for (m, role) in [
            (Some(&o.material), "material"),
            (leaf_material(o), "shape.leaf_material"),
        ] {
            if let Some(BaseColor::Image { path, .. }) = m.map(|m| &m.base) {
                let key = format!("objects[{i}].{role}.base.path");
                check(key, path, TEXTURE_EXTENSIONS, true)?;
            }
        }
    }
    Ok(())
}

fn leaf_material(o: &crate::plan::ObjectSpec) -> Option<&crate::plan::MaterialSpec> {
    match &o.shape {
        Shape::Skeleton { leaf_material, .. } => leaf_material.as_deref(),
        _ => None,
    }
}

/// A PNG's or JPEG's size from its header, where the `image` crate can read one.
fn image_header_size(path: &Path) -> Option<(u32, u32)> {
    image::ImageReader::open(path)
        .ok()?
        .with_guessed_format()
        .ok()?
        .into_dimensions()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{AssetIndex, Recipe, plan_scene};

    fn tree_spec() -> SceneSpec {
        plan_scene(
            &Recipe::preset("tree").unwrap(),
            &AssetIndex::default(),
            11,
            3,
        )
    }

    #[test]
    fn gzip_and_plain_files_read_back_the_same_spec_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let spec = tree_spec();
        for name in ["a.scene.json.gz", "a.scene.json"] {
            let path = dir.path().join(name);
            write_scene_spec(&path, &spec).unwrap();
            let back = read_scene_spec(&path).unwrap();
            assert_eq!(back, spec, "{name}");
            assert_eq!(
                back.to_json(),
                spec.to_json(),
                "{name}: every float survives"
            );
        }
        let gz = std::fs::metadata(dir.path().join("a.scene.json.gz"))
            .unwrap()
            .len();
        let plain = std::fs::metadata(dir.path().join("a.scene.json"))
            .unwrap()
            .len();
        assert!(gz * 3 < plain, "gzip {gz} B vs plain {plain} B");
    }

    #[test]
    fn content_decides_not_the_name_and_encoding_is_deterministic() {
        let dir = tempfile::tempdir().unwrap();
        let spec = tree_spec();
        // An older dataset's plain JSON under the new name, and gzip under the old one, both read.
        let plain_as_gz = dir.path().join("b.scene.json.gz");
        std::fs::write(&plain_as_gz, spec.to_json()).unwrap();
        assert_eq!(read_scene_spec(&plain_as_gz).unwrap(), spec);
        let gz_as_plain = dir.path().join("b.scene.json");
        std::fs::write(&gz_as_plain, encode_scene_spec(Path::new("x.gz"), &spec)).unwrap();
        assert_eq!(read_scene_spec(&gz_as_plain).unwrap(), spec);
        assert_eq!(
            encode_scene_spec(Path::new("x.gz"), &spec),
            encode_scene_spec(Path::new("y.gz"), &spec)
        );
    }

    #[test]
    fn damaged_files_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.scene.json.gz");
        let mut bytes = encode_scene_spec(&path, &tree_spec());
        bytes.truncate(bytes.len() / 2);
        std::fs::write(&path, bytes).unwrap();
        let e = format!("{:#}", read_scene_spec(&path).unwrap_err());
        assert!(e.contains("c.scene.json.gz") && e.contains("gzip"), "{e}");
    }
}
