//! Turns a worker's intermediate files into a finished sample: depth → disparity for both views,
//! files renamed into place, then the manifest entry describing them.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, bail};
use sha2::{Digest, Sha256};
use stereo_io::{DisparityMap, DisparityMeta};

use super::layout::DatasetLayout;
use super::manifest::{DisparitySummary, ManifestEntry};
use crate::plan::SceneSpec;
use crate::render::protocol::RenderedFiles;

fn summary(map: &DisparityMap) -> Option<DisparitySummary> {
    map.stats().map(|s| DisparitySummary { min: s.min, max: s.max, mean: s.mean, valid_fraction: s.valid_pixels as f64 / map.data.len() as f64 })
}

/// Reads a Cycles depth EXR and converts it to disparity with the spec's rig.
pub fn disparity_from_depth_exr(path: &Path, spec: &SceneSpec) -> anyhow::Result<DisparityMap> {
    let (w, h, depth) = stereo_io::read_depth_channel(path)?;
    if (w, h) != (spec.rig.width as usize, spec.rig.height as usize) {
        bail!("{}: depth is {w}x{h}, the spec asks for {}x{}", path.display(), spec.rig.width, spec.rig.height);
    }
    // Cycles writes 1e10 where a ray escapes; nothing real lies beyond the far clip.
    Ok(DisparityMap::from_depth(w, h, &depth, spec.rig.f_px(), spec.rig.baseline_m, spec.render.clip_end as f32))
}

fn sha256_file(path: &Path) -> anyhow::Result<String> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read back {}", path.display()))?;
    Ok(Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

/// Re-encodes the worker's PNG: Cycles writes render times into PNG text chunks, so a plain copy
/// would make every re-render of a spec a different file. Decoding also checks the image.
fn write_canonical_png(from: &Path, to: &Path, spec: &SceneSpec) -> anyhow::Result<()> {
    let img = stereo_io::read_rgb(from)?;
    if (img.width, img.height) != (spec.rig.width as usize, spec.rig.height as usize) {
        bail!("{}: image is {}x{}, the spec asks for {}x{}", from.display(), img.width, img.height, spec.rig.width, spec.rig.height);
    }
    stereo_io::write_atomically(to, |tmp| stereo_io::write_png_rgb(tmp, &img)).with_context(|| format!("cannot write {}", to.display()))
}

/// Writes all files of a rendered sample into the dataset and returns its manifest entry.
/// Each file appears atomically; the caller appends the entry to the manifest last.
/// `render_timings` is where the worker says its time went (stage → seconds).
pub fn finalize_sample(layout: &DatasetLayout, spec: &SceneSpec, files: &RenderedFiles, notes: &[String], render_seconds: f64, render_timings: &BTreeMap<String, f64>) -> anyhow::Result<ManifestEntry> {
    let paths = layout.sample_paths(&spec.category, &spec.id);
    let dir = layout.abs(&paths.left).parent().expect("category dir").to_path_buf();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;

    let f_px = spec.rig.f_px();
    let disp_left = disparity_from_depth_exr(&files.left_depth_exr, spec)?;
    let disp_right = disparity_from_depth_exr(&files.right_depth_exr, spec)?;
    for (map, rel, view) in [(&disp_left, &paths.disp_left, "left"), (&disp_right, &paths.disp_right, "right")] {
        let meta = DisparityMeta { f_px: Some(f_px), baseline_m: Some(spec.rig.baseline_m), view: Some(view.into()) };
        let path = layout.abs(rel);
        stereo_io::write_atomically(&path, |tmp| stereo_io::write_disparity_exr(tmp, map, &meta)).with_context(|| format!("cannot write {}", path.display()))?;
    }
    write_canonical_png(&files.left_png, &layout.abs(&paths.left), spec)?;
    write_canonical_png(&files.right_png, &layout.abs(&paths.right), spec)?;
    let scene_path = layout.abs(&paths.scene);
    super::scene_file::write_scene_spec(&scene_path, spec)?;

    let mut sha256 = BTreeMap::new();
    for (key, rel) in paths.all() {
        sha256.insert(key.to_string(), sha256_file(&layout.abs(rel))?);
    }
    let (cx, cy) = spec.rig.principal_point();
    Ok(ManifestEntry {
        id: spec.id.clone(),
        category: spec.category.clone(),
        seed: spec.seed,
        index: spec.index,
        files: paths,
        width: spec.rig.width,
        height: spec.rig.height,
        f_px,
        baseline_m: spec.rig.baseline_m,
        cx,
        cy,
        disparity_left: summary(&disp_left),
        disparity_right: summary(&disp_right),
        render_seconds,
        render_timings: render_timings.clone(),
        notes: notes.to_vec(),
        sha256,
        stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
    })
}
