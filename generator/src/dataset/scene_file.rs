//! A sample's `scene.json`: the SceneSpec that reproduces it. Every reader and writer of the file
//! goes through here, so how it is stored on disk is decided in one place.

use std::path::Path;

use anyhow::Context;

use crate::plan::SceneSpec;

/// Writes `spec` to `path` atomically.
pub fn write_scene_spec(path: &Path, spec: &SceneSpec) -> anyhow::Result<()> {
    stereo_io::write_bytes_atomically(path, spec.to_json().as_bytes()).with_context(|| format!("cannot write {}", path.display()))
}

/// Reads the SceneSpec stored at `path`; the error names the file and the problem.
pub fn read_scene_spec(path: &Path) -> anyhow::Result<SceneSpec> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    SceneSpec::from_json(&text).with_context(|| format!("{}: not a SceneSpec", path.display()))
}
