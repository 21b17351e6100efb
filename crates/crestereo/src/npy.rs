//! `.npy` / `.npz` fixtures, read through `stereo-io` (the project's one NumPy reader).

use std::path::Path;

use anyhow::Result;

/// An array as float32 values (row-major) with its shape.
pub type Array = stereo_io::NpyArray;

/// Reads a `.npy` file.
pub fn read_npy(path: impl AsRef<Path>) -> Result<Array> {
    Ok(stereo_io::read_npy(path.as_ref())?)
}

/// Reads every array of a `.npz` file (names without the `.npy` suffix).
pub fn read_npz(path: impl AsRef<Path>) -> Result<Vec<(String, Array)>> {
    Ok(stereo_io::read_npz(path.as_ref())?)
}
