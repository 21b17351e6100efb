//! A sample's `scene.json`: the SceneSpec that reproduces it. Every reader and writer of the file
//! goes through here, so how it is stored on disk is decided in one place.

use std::path::Path;

use anyhow::Context;

use crate::plan::SceneSpec;

/// Writes `spec` to `path` durably (the error names the path and the OS error).
pub fn write_scene_spec(path: &Path, spec: &SceneSpec) -> anyhow::Result<()> {
    Ok(stereo_io::write_bytes_atomically(path, spec.to_json().as_bytes())?)
}

/// Reads the SceneSpec stored at `path`; the error names the file and the problem.
pub fn read_scene_spec(path: &Path) -> anyhow::Result<SceneSpec> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
    SceneSpec::from_json(&text).with_context(|| format!("{}: not a SceneSpec", path.display()))
}

/// [`read_scene_spec`], then [`check_scene_spec`]: a spec that is about to be rendered.
pub fn read_renderable_spec(path: &Path) -> anyhow::Result<SceneSpec> {
    let spec = read_scene_spec(path)?;
    check_scene_spec(&spec).with_context(|| format!("{}: cannot be rendered", path.display()))?;
    Ok(spec)
}

/// Checks what Blender would otherwise be asked to render: an image size it can make, and a rig
/// and clipping range whose numbers stay finite through every derived quantity. The message names
/// the key and the value. (Specs the planner writes always pass: the recipe's own bounds are
/// narrower.)
pub fn check_scene_spec(spec: &SceneSpec) -> anyhow::Result<()> {
    let rig = &spec.rig;
    let render = &spec.render;
    let positive = |key: &str, v: f64, max: f64| -> anyhow::Result<()> {
        if !(v.is_finite() && v > 0.0 && v <= max) {
            anyhow::bail!("`{key}` = {v} is invalid: need 0 < {key} <= {max}");
        }
        Ok(())
    };
    for (key, v) in [("rig.width", rig.width), ("rig.height", rig.height)] {
        if !(1..=16384).contains(&v) {
            anyhow::bail!("`{key}` = {v} is invalid: need 1..=16384 pixels");
        }
    }
    positive("rig.focal_mm", rig.focal_mm, 1e4)?;
    positive("rig.sensor_width_mm", rig.sensor_width_mm, 1e3)?;
    positive("rig.baseline_m", rig.baseline_m, 1e3)?;
    positive("render.clip_start", render.clip_start, 1e6)?;
    positive("render.clip_end", render.clip_end, 1e9)?;
    if render.clip_end <= render.clip_start {
        anyhow::bail!("`render.clip_end` = {} is invalid: it must lie beyond render.clip_start = {}", render.clip_end, render.clip_start);
    }
    if !(1..=65536).contains(&render.samples) {
        anyhow::bail!("`render.samples` = {} is invalid: need 1..=65536", render.samples);
    }
    positive("render.filter_width_px", render.filter_width_px, 10.0)?;
    Ok(())
}
