//! Turns a worker's intermediate files into a finished sample: depth → disparity for both views,
//! files written durably into place, every file read back and checked, then the manifest entry
//! describing them.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use stereo_io::datasets::stereogen::{Difficulty, VIEWS};
use stereo_io::datasets::{MapData, SampleMaps};
use stereo_io::digest::sha256_hex;
use stereo_io::{DisparityMap, DisparityMeta, MapKind, RenderPasses, RgbImage};

use super::layout::{DatasetLayout, SamplePaths};
use super::manifest::{DisparitySummary, ManifestEntry};
use super::sample_maps::{instance_table, requested_maps, view_maps};
use crate::plan::SceneSpec;
use crate::render::protocol::RenderedFiles;

/// Keys the generator adds to a manifest entry's `render_timings`, beside the worker's steps:
/// seconds spent decoding the worker's PNGs, reading its depth EXRs and converting them to
/// disparity, writing the sample's files, and reading them back to verify them.
pub const DECODE_PNG_TIMING: &str = "decode_png_s";
pub const CONVERT_TIMING: &str = "convert_s";
pub const WRITE_TIMING: &str = "write_s";
pub const VERIFY_TIMING: &str = "verify_s";
/// Measuring the sample's [`Difficulty`] facts.
pub const DIFFICULTY_TIMING: &str = "difficulty_s";

/// Reads a Cycles depth EXR and converts it to disparity with the spec's rig.
pub fn disparity_from_depth_exr(path: &Path, spec: &SceneSpec) -> anyhow::Result<DisparityMap> {
    Ok(read_depth_pass(path, spec)?.0)
}

/// Reads a Cycles depth EXR: its depth converted to disparity with the spec's rig, and all its
/// passes (the material index where the worker rendered it, the passes of the maps asked for).
pub fn read_depth_pass(
    path: &Path,
    spec: &SceneSpec,
) -> anyhow::Result<(DisparityMap, RenderPasses)> {
    let passes = stereo_io::read_render_passes(path)?;
    let (w, h, depth) = (passes.width, passes.height, &passes.depth);
    if (w, h) != (spec.rig.width as usize, spec.rig.height as usize) {
        bail!(
            "{}: depth is {w}x{h}, the spec asks for {}x{}",
            path.display(),
            spec.rig.width,
            spec.rig.height
        );
    }
    // Cycles writes 1e10 where a ray escapes; nothing real lies beyond the far clip.
    let map = DisparityMap::from_depth(
        w,
        h,
        depth,
        spec.rig.f_px(),
        spec.rig.baseline_m,
        spec.render.clip_end as f32,
    );
    Ok((map, passes))
}

/// The worker's PNG decoded. It is re-encoded, not copied: Cycles writes render times into PNG
/// text chunks, so a plain copy would make every re-render of a spec a different file.
fn read_worker_png(from: &Path, spec: &SceneSpec) -> anyhow::Result<RgbImage> {
    let img = stereo_io::read_rgb(from)?;
    if (img.width, img.height) != (spec.rig.width as usize, spec.rig.height as usize) {
        bail!(
            "{}: image is {}x{}, the spec asks for {}x{}",
            from.display(),
            img.width,
            img.height,
            spec.rig.width,
            spec.rig.height
        );
    }
    Ok(img)
}

/// What a sample's files must hold: the read-back check compares against it.
struct SampleContent<'a> {
    spec: &'a SceneSpec,
    left: RgbImage,
    right: RgbImage,
    disp_left: DisparityMap,
    disp_right: DisparityMap,
    maps: SampleMaps,
}

impl SampleContent<'_> {
    fn meta(&self, view: &str) -> DisparityMeta {
        DisparityMeta {
            f_px: Some(self.spec.rig.f_px()),
            baseline_m: Some(self.spec.rig.baseline_m),
            view: Some(view.into()),
        }
    }

    /// Writes every file durably (each one whole under its final name, or not at all).
    fn write(&self, layout: &DatasetLayout, paths: &SamplePaths) -> anyhow::Result<()> {
        stereo_io::write_disparity_exr(
            &layout.abs(&paths.disp_left),
            &self.disp_left,
            &self.meta("left"),
        )?;
        stereo_io::write_disparity_exr(
            &layout.abs(&paths.disp_right),
            &self.disp_right,
            &self.meta("right"),
        )?;
        stereo_io::write_png_rgb(&layout.abs(&paths.left), &self.left)?;
        stereo_io::write_png_rgb(&layout.abs(&paths.right), &self.right)?;
        for view in VIEWS {
            for kind in MapKind::ALL {
                if let Some(bytes) = self.maps.view(view).encode(kind, view) {
                    let rel = paths
                        .map(kind, view)
                        .expect("the paths name every map asked for");
                    let path = layout.abs(rel);
                    let bytes = bytes.map_err(|m| stereo_io::Error::format(&path, m))?;
                    stereo_io::write_bytes_atomically(&path, &bytes)?;
                }
            }
        }
        super::scene_file::write_scene_spec(&layout.abs(&paths.scene), self.spec)
    }

    /// Whether the map file with key `key` (`depth_left`, ...) decodes to what was written.
    fn map_is_same(&self, key: &str, path: &Path, bytes: &[u8]) -> anyhow::Result<bool> {
        let missing = || anyhow::anyhow!("file key {key:?} names no map that was made");
        let (kind, view) = key
            .rsplit_once('_')
            .and_then(|(name, view)| Some((MapKind::from_name(name)?, view)))
            .filter(|(kind, view)| VIEWS.contains(view) && self.maps.view(view).has(*kind))
            .ok_or_else(missing)?;
        let back = MapData::decode(kind, bytes, path)?;
        Ok(self.maps.view(view).holds(kind, &back))
    }

    /// Checks the bytes read back from the file with key `key` against what was written.
    fn check(&self, key: &str, path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
        let same = match key {
            "left" | "right" => {
                let expected = if key == "left" {
                    &self.left
                } else {
                    &self.right
                };
                let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
                    .with_context(|| {
                        format!("{}: cannot decode the PNG read back", path.display())
                    })?;
                img.width() as usize == expected.width
                    && img.height() as usize == expected.height
                    && img.to_rgb8().as_raw() == &expected.data
            }
            "disp_left" | "disp_right" => {
                let expected = if key == "disp_left" {
                    &self.disp_left
                } else {
                    &self.disp_right
                };
                let (map, _) = stereo_io::decode_disparity_exr(bytes, path)?;
                (map.width, map.height) == (expected.width, expected.height)
                    && map.valid == expected.valid
                    && map
                        .data
                        .iter()
                        .zip(&expected.data)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
            }
            "scene" => {
                // Gzip'd or plain, decoded the way every reader decodes it.
                super::scene_file::decode_scene_spec(bytes)
                    .with_context(|| format!("{}: not a SceneSpec", path.display()))?
                    == *self.spec
            }
            other => self.map_is_same(other, path, bytes)?,
        };
        if !same {
            bail!(
                "{}: what was read back differs from what was written",
                path.display()
            );
        }
        Ok(())
    }

    /// Reads every file back from the disk, decodes it fully, compares it with what was
    /// written, and returns its SHA-256 taken from the bytes read.
    fn verify(
        &self,
        layout: &DatasetLayout,
        paths: &SamplePaths,
    ) -> anyhow::Result<BTreeMap<String, String>> {
        let mut sha256 = BTreeMap::new();
        for (key, rel) in paths.all() {
            let path = layout.abs(rel);
            let bytes = read_back(&path)?;
            self.check(key, &path, &bytes)?;
            sha256.insert(key.to_string(), sha256_hex(&bytes));
        }
        Ok(sha256)
    }
}

/// Reads a file that was just written and synced, from the storage rather than from the page
/// cache where the kernel can (its clean pages are dropped first), so a write the device or the
/// network filesystem lost shows up here.
fn read_back(path: &Path) -> anyhow::Result<Vec<u8>> {
    use std::io::Read;
    let mut file = std::fs::File::open(path)
        .with_context(|| format!("{}: cannot read back", path.display()))?;
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        // Advice only: where the kernel keeps the pages (tmpfs) the read comes from memory.
        unsafe { libc::posix_fadvise(file.as_raw_fd(), 0, 0, libc::POSIX_FADV_DONTNEED) };
    }
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes)
        .with_context(|| format!("{}: cannot read back", path.display()))?;
    Ok(bytes)
}

/// Writes all files of a rendered sample into the dataset, reads each back (fully decoded and
/// compared with what was written; checksums taken from what was read) and returns its manifest
/// entry; the caller appends the entry to the manifest last. On any error nothing of the sample
/// stays in the dataset. `render_timings` is where the worker says its time went (stage →
/// seconds); [`DECODE_PNG_TIMING`], [`CONVERT_TIMING`], [`WRITE_TIMING`], [`VERIFY_TIMING`] and
/// [`DIFFICULTY_TIMING`] are added, and `render_seconds` (the time before this call) grows by
/// all five.
pub fn finalize_sample(
    layout: &DatasetLayout,
    spec: &SceneSpec,
    files: &RenderedFiles,
    notes: &[String],
    render_seconds: f64,
    render_timings: &BTreeMap<String, f64>,
) -> anyhow::Result<ManifestEntry> {
    let maps = requested_maps(spec);
    let paths = SamplePaths::with_maps(&spec.category, &spec.id, &maps);
    let dir = layout
        .abs(&paths.left)
        .parent()
        .expect("category dir")
        .to_path_buf();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;

    let t0 = Instant::now();
    let (disp_left, passes_left) = read_depth_pass(&files.left_depth_exr, spec)?;
    let (disp_right, passes_right) = read_depth_pass(&files.right_depth_exr, spec)?;
    let sample_maps = SampleMaps {
        left: view_maps(&maps, &passes_left, &disp_left, spec, "left view")?,
        right: view_maps(&maps, &passes_right, &disp_right, spec, "right view")?,
    };
    let material_index = passes_left.material_index;
    let convert_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let left = read_worker_png(&files.left_png, spec)?;
    let right = read_worker_png(&files.right_png, spec)?;
    let decode_png_s = t0.elapsed().as_secs_f64();
    let content = SampleContent {
        spec,
        disp_left,
        disp_right,
        left,
        right,
        maps: sample_maps,
    };
    let t0 = Instant::now();
    let written = content.write(layout, &paths).and_then(|()| {
        let write_s = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        Ok((
            write_s,
            content.verify(layout, &paths)?,
            t1.elapsed().as_secs_f64(),
        ))
    });
    let (write_s, sha256, verify_s) = match written {
        Ok(w) => w,
        Err(e) => {
            remove_sample_files(layout, &paths);
            return Err(e);
        }
    };
    let t0 = Instant::now();
    let difficulty = Difficulty::measure(
        &content.left,
        &content.disp_left,
        &content.disp_right,
        material_index.as_deref(),
    );
    let difficulty_s = t0.elapsed().as_secs_f64();
    let mut timings = render_timings.clone();
    timings.insert(DIFFICULTY_TIMING.to_string(), difficulty_s);
    timings.insert(CONVERT_TIMING.to_string(), convert_s);
    timings.insert(DECODE_PNG_TIMING.to_string(), decode_png_s);
    timings.insert(WRITE_TIMING.to_string(), write_s);
    timings.insert(VERIFY_TIMING.to_string(), verify_s);
    let (cx, cy) = spec.rig.principal_point();
    Ok(ManifestEntry {
        id: spec.id.clone(),
        category: spec.category.clone(),
        seed: spec.seed,
        index: spec.index,
        files: paths,
        width: spec.rig.width,
        height: spec.rig.height,
        f_px: spec.rig.f_px(),
        baseline_m: spec.rig.baseline_m,
        cx,
        cy,
        disparity_left: DisparitySummary::of(&content.disp_left),
        disparity_right: DisparitySummary::of(&content.disp_right),
        difficulty: Some(difficulty),
        render_seconds: render_seconds
            + convert_s
            + decode_png_s
            + write_s
            + verify_s
            + difficulty_s,
        render_timings: timings,
        instances: if maps.contains(&MapKind::Instance) || maps.contains(&MapKind::Semantic) {
            instance_table(spec, notes)
        } else {
            Vec::new()
        },
        notes: notes.to_vec(),
        sha256,
        stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
    })
}

/// Removes whatever files of a sample that failed to finish are in place (it has no manifest
/// line, so none of them is part of the dataset).
fn remove_sample_files(layout: &DatasetLayout, paths: &SamplePaths) {
    for (_, rel) in paths.all() {
        let path: PathBuf = layout.abs(rel);
        let _ = stereo_io::atomic::remove_file_durably(&path);
    }
}
