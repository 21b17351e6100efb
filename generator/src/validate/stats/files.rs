//! Reading one file of a sample for the stats pass, with `--verify`'s checks; a problem is a
//! typed [`FileError`] that names its file once.

use std::fmt;
use std::path::PathBuf;

use stereo_io::digest::sha256_hex;

use crate::dataset::ManifestEntry;
use crate::validate::dataset_files::DatasetFiles;

/// A file of a sample that could not be read or failed verification.
#[derive(Debug)]
pub enum FileError {
    /// Reading or decoding failed (stereo-io's error names the file).
    Io(stereo_io::Error),
    /// `--verify`: the manifest has no checksum for the file.
    NoChecksum(PathBuf),
    /// `--verify`: the file is not the one the manifest recorded.
    ChecksumDiffers {
        path: PathBuf,
        actual: String,
        recorded: String,
    },
    /// `--verify`: an image that does not decode.
    Undecodable { path: PathBuf, message: String },
    /// A scene file that holds no SceneSpec.
    NotASceneSpec { path: PathBuf, message: String },
}

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FileError::Io(e) => write!(f, "{e}"),
            FileError::NoChecksum(path) => write!(
                f,
                "{}: the manifest records no checksum for it",
                path.display()
            ),
            FileError::ChecksumDiffers {
                path,
                actual,
                recorded,
            } => write!(
                f,
                "{}: SHA-256 {actual} differs from the manifest's {recorded}",
                path.display()
            ),
            FileError::Undecodable { path, message } => {
                write!(f, "{}: cannot decode: {message}", path.display())
            }
            FileError::NotASceneSpec { path, message } => {
                write!(f, "{}: not a SceneSpec: {message}", path.display())
            }
        }
    }
}

/// Reads one file of a sample (from its folder or its export's shard): with `verify`, its
/// checksum is compared with the manifest's and an image is decoded in full. Returns the bytes
/// read.
pub fn read_sample_file(
    files: &DatasetFiles,
    e: &ManifestEntry,
    key: &str,
    verify: bool,
) -> Result<Vec<u8>, FileError> {
    let bytes = files.read(e, key).map_err(FileError::Io)?;
    if verify {
        let path = files.path(e, key);
        let Some(recorded) = e.sha256.get(key) else {
            return Err(FileError::NoChecksum(path));
        };
        let actual = sha256_hex(&bytes);
        if &actual != recorded {
            return Err(FileError::ChecksumDiffers {
                path,
                actual,
                recorded: recorded.clone(),
            });
        }
        if matches!(key, "left" | "right") {
            image::load_from_memory(&bytes).map_err(|err| FileError::Undecodable {
                path: path.clone(),
                message: err.to_string(),
            })?;
        }
    }
    Ok(bytes)
}

/// Verifies the files the pixel pass does not read (images and the scene file, which an export
/// may not carry).
pub fn verify_other_files(files: &DatasetFiles, e: &ManifestEntry) -> Vec<FileError> {
    ["left", "right", "scene"]
        .into_iter()
        .filter(|key| files.has(e, key))
        .filter_map(|key| read_sample_file(files, e, key, true).err())
        .collect()
}
