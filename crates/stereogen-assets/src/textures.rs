//! Photo folders used as textures. Each file's header is decoded once at index time, so files
//! that are not images are skipped and listed rather than failing a render.

use std::path::Path;

use anyhow::bail;
use stereogen_plan::assets::{SkippedAsset, TextureAsset};

use super::folder::index_files;

/// Extensions Blender loads as textures.
pub const TEXTURE_EXTENSIONS: &[&str] = &[
    "png", "jpg", "jpeg", "tif", "tiff", "bmp", "tga", "exr", "hdr", "webp",
];

fn probe(path: &Path) -> Result<(u32, u32), String> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| e.to_string())?
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    if reader.format().is_none() {
        return Err("not a recognised image format".into());
    }
    let (w, h) = reader.into_dimensions().map_err(|e| e.to_string())?;
    if w == 0 || h == 0 {
        return Err("image has no pixels".into());
    }
    // Blender decodes a photo whole before the worker scales it down: one over the readers'
    // limits (a small PNG may claim 30000×30000 pixels) is left out like a broken one.
    if let Some(problem) = stereo_io::limits::image_size_problem(w.into(), h.into()) {
        return Err(problem);
    }
    Ok((w, h))
}

/// Indexes every image under `root`, with its pixel size where the header can be read.
pub fn index_textures(
    root: &Path,
    home: &Path,
) -> anyhow::Result<(Vec<TextureAsset>, Vec<SkippedAsset>)> {
    let (found, skipped) = index_files(root, home, "texture", "photos", |entry| {
        let ext = entry
            .path()
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if !entry.file_type().is_file()
            || !ext
                .as_deref()
                .is_some_and(|e| TEXTURE_EXTENSIONS.contains(&e))
        {
            return None;
        }
        // image cannot probe every format Blender reads (EXR/HDR/TGA need features we do not build).
        let probed = matches!(
            ext.as_deref(),
            Some("png" | "jpg" | "jpeg" | "tif" | "tiff" | "bmp" | "webp")
        );
        let size = match probed.then(|| probe(entry.path())) {
            None => None,
            Some(Ok((w, h))) => Some([w, h]),
            // Decoders end some messages with a newline.
            Some(Err(reason)) => return Some(Err(reason.trim().to_string())),
        };
        Some(Ok(TextureAsset {
            path: entry.path().to_path_buf(),
            size,
        }))
    })?;
    if found.is_empty() {
        bail!(
            "texture folder {} holds no readable images ({})",
            root.display(),
            TEXTURE_EXTENSIONS.join(", ")
        );
    }
    Ok((found, skipped))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrupt_images_are_skipped_and_listed() {
        let root = tempfile::tempdir().unwrap();
        let home = tempfile::tempdir().unwrap();
        let good = root.path().join("good.png");
        image::RgbImage::from_pixel(4, 4, image::Rgb([10, 200, 30]))
            .save(&good)
            .unwrap();
        std::fs::write(root.path().join("bad.jpg"), b"this is not a jpeg").unwrap();
        std::fs::write(root.path().join("notes.txt"), b"ignored").unwrap();
        let (found, skipped) = index_textures(root.path(), home.path()).unwrap();
        assert_eq!(
            found,
            vec![TextureAsset {
                path: good,
                size: Some([4, 4])
            }]
        );
        assert_eq!(skipped.len(), 1);
        assert!(skipped[0].path.ends_with("bad.jpg"));
    }
}
