//! `manifest.jsonl`: one JSON line per finished sample, appended by `stereogen generate` only
//! after all of the sample's files are in place.
//!
//! An unfinished last line (no newline yet: an append in progress or one torn by a kill) is
//! never an entry, whatever it holds (the rule of [`super::json_lines`]). [`read_manifest`]
//! leaves it out and reports it in [`ManifestContents::unfinished_bytes`]; only
//! [`Manifest::open`], the writer's open, cuts it off the file.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::SamplePaths;
use super::difficulty::Difficulty;
use super::json_lines::read_finished_lines;
use crate::error::{Error, Result};
use crate::limits::relative_path_buf_problem;

/// Statistics of the valid pixels of one view's disparity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DisparitySummary {
    pub min: f32,
    pub max: f32,
    pub mean: f64,
    pub valid_fraction: f64,
}

impl DisparitySummary {
    /// The summary of `map`'s valid pixels; `None` when it has none.
    pub fn of(map: &crate::DisparityMap) -> Option<Self> {
        map.stats().map(|s| DisparitySummary {
            min: s.min,
            max: s.max,
            mean: s.mean,
            valid_fraction: s.valid_pixels as f64 / map.data.len() as f64,
        })
    }
}

/// One object of a sample, as its `instance` maps name it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InstanceRecord {
    /// The value of its pixels in the instance maps (1 and up; 0 is no surface).
    pub id: u16,
    /// Its name in the sample's SceneSpec.
    pub name: String,
    /// `background` (the wall behind the scene) or `content` (placed by the disparity law).
    pub role: String,
    /// What made it: `wall`, `primitive`, `shapenet`, `meshes`, `tree`, `wireframe`, `net`.
    pub source: String,
    /// The mesh file it was planned from (ShapeNet model, mesh folder), where it has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// Its material class (`textured`, `textureless`, `glossy`, `metallic`, `glass`).
    pub material: String,
    /// Its class id in the semantic maps (the dataset's `semantic_classes`).
    pub semantic: u16,
}

/// One finished sample, as one manifest line.
///
/// Required in every line: the identity (`id`, `category`, `index`), the `files` and the camera
/// (`width`, `height`, `f_px`, `baseline_m`, `cx`, `cy`). The rest is provenance and summaries;
/// a line without them (an older or hand-made manifest) reads with their defaults. Unknown
/// fields are ignored, so newer manifests still read here.
///
/// Camera: square pixels, both views share the intrinsics and sit `baseline_m` apart along x.
/// `cx`, `cy` are in **continuous image coordinates** (pixel `i` covers `[i, i + 1)`, its centre
/// is at `i + 0.5`), so a centred principal point is `(width/2, height/2)`; see
/// [`crate::pixel_coords`] for the conversion to the pixel-centre convention of OpenCV and
/// Middlebury.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ManifestEntry {
    pub id: String,
    pub category: String,
    /// The dataset's seed (also in `dataset.json`).
    #[serde(default)]
    pub seed: u64,
    pub index: u64,
    pub files: SamplePaths,
    pub width: u32,
    pub height: u32,
    /// Focal length in pixels.
    pub f_px: f64,
    pub baseline_m: f64,
    /// Principal point, continuous image coordinates.
    pub cx: f64,
    pub cy: f64,
    /// Statistics of the valid pixels of each view; `None` when a view has none.
    #[serde(default)]
    pub disparity_left: Option<DisparitySummary>,
    #[serde(default)]
    pub disparity_right: Option<DisparitySummary>,
    /// What makes the sample hard to match ([`Difficulty`]); absent in lines written before it
    /// was measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub difficulty: Option<Difficulty>,
    /// Wall seconds from handing the spec to a worker to the sample being finished.
    #[serde(default)]
    pub render_seconds: f64,
    /// Where the worker's time went (stage name → seconds), as the worker reports it.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub render_timings: BTreeMap<String, f64>,
    /// What the worker did beyond the spec (which mesh candidate it used, objects it dropped).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
    /// The objects the instance maps name (when the dataset has them), by id.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub instances: Vec<InstanceRecord>,
    /// SHA-256 of each file, keyed like `files`.
    #[serde(default)]
    pub sha256: BTreeMap<String, String>,
    #[serde(default)]
    pub stereogen_version: String,
}

/// The finished entries of a manifest, and what was left out.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ManifestContents {
    pub entries: Vec<ManifestEntry>,
    /// Bytes of an unfinished last line (no newline yet) that was left out; 0 when none.
    pub unfinished_bytes: u64,
}

impl ManifestContents {
    /// Whether an unfinished last line was left out (a run writing, or a torn append).
    pub fn has_unfinished_line(&self) -> bool {
        self.unfinished_bytes > 0
    }
}

/// Reads the finished entries of the manifest at `path` (see the module docs for the rule).
pub fn read_manifest(path: &Path) -> Result<ManifestContents> {
    let file =
        File::open(path).map_err(|e| unmerged_farm_error(path).unwrap_or(Error::io(path, e)))?;
    read_manifest_from(BufReader::new(file), path)
}

/// A missing manifest in a farm's output directory means its shards are not merged yet.
fn unmerged_farm_error(path: &Path) -> Option<Error> {
    super::DatasetLayout::new(path.parent()?).unmerged_error(path)
}

/// [`read_manifest`] of the bytes of `reader` (`path` names them in errors).
pub fn read_manifest_from(reader: impl BufRead, path: &Path) -> Result<ManifestContents> {
    let mut entries = Vec::new();
    let unfinished_bytes = read_finished_lines(reader, path, |number, text| {
        let entry: ManifestEntry = serde_json::from_str(text).map_err(|e| {
            Error::format(path, format!("line {number} is not a manifest entry: {e}"))
        })?;
        // Readers open these paths under the dataset's root: none may lead out of it.
        for (key, rel) in entry.files.all() {
            if let Some(problem) = relative_path_buf_problem(rel) {
                return Err(Error::format(
                    path,
                    format!(
                        "line {number}: the path of `files.{key}` {problem}; a manifest names files inside its dataset only"
                    ),
                ));
            }
        }
        entries.push(entry);
        Ok(())
    })?;
    Ok(ManifestContents {
        entries,
        unfinished_bytes,
    })
}

/// The manifest opened by its one writer, for appending.
pub struct Manifest {
    path: PathBuf,
    file: File,
}

impl Manifest {
    /// Opens (or creates) the manifest for appending and returns what it already holds. An
    /// unfinished last line can only be a torn append here (the caller holds the dataset's
    /// lock, so nobody else writes): it is cut off the file, and reported in the contents.
    pub fn open(path: &Path) -> Result<(Self, ManifestContents)> {
        let mut file = OpenOptions::new()
            .create(true)
            .read(true)
            .append(true)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        let contents = read_manifest_from(BufReader::new(&file), path)?;
        if contents.has_unfinished_line() {
            let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
            file.set_len(len - contents.unfinished_bytes)
                .map_err(|e| Error::io(path, e))?;
            file.seek(SeekFrom::End(0))
                .map_err(|e| Error::io(path, e))?;
        }
        Ok((
            Self {
                path: path.to_path_buf(),
                file,
            },
            contents,
        ))
    }

    /// Appends one entry as one line and syncs it to disk before returning.
    pub fn append(&mut self, entry: &ManifestEntry) -> Result<()> {
        let mut line = serde_json::to_string(entry).map_err(|e| {
            Error::format(&self.path, format!("cannot encode entry {}: {e}", entry.id))
        })?;
        line.push('\n');
        // One write of the whole line: a reader sees the line entire or unfinished, never two halves.
        self.file
            .write_all(line.as_bytes())
            .map_err(|e| Error::io(&self.path, e))?;
        self.file.sync_data().map_err(|e| Error::io(&self.path, e))
    }

    /// The finished entries of a manifest ([`read_manifest`] without the count of what was left out).
    pub fn read(path: &Path) -> Result<Vec<ManifestEntry>> {
        Ok(read_manifest(path)?.entries)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(index: u64) -> ManifestEntry {
        let id = format!("{index:07}");
        ManifestEntry {
            files: SamplePaths::new("tree", &id),
            id,
            category: "tree".into(),
            seed: 3,
            index,
            width: 8,
            height: 6,
            f_px: 10.0,
            baseline_m: 0.1,
            cx: 4.0,
            cy: 3.0,
            disparity_left: None,
            disparity_right: Some(DisparitySummary {
                min: 1.0,
                max: 2.0,
                mean: 1.5,
                valid_fraction: 0.5,
            }),
            difficulty: None,
            render_seconds: 1.25,
            render_timings: BTreeMap::from([("save".to_string(), 0.25)]),
            notes: vec![],
            instances: Vec::new(),
            sha256: BTreeMap::new(),
            stereogen_version: "0.1.0".into(),
        }
    }

    fn line(e: &ManifestEntry) -> String {
        serde_json::to_string(e).unwrap() + "\n"
    }

    #[test]
    fn an_unfinished_last_line_is_left_out_and_counted_even_when_it_parses() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("manifest.jsonl");
        let whole = line(&entry(1));
        for tail in [&whole[..whole.len() / 2], whole.trim_end()] {
            std::fs::write(&path, line(&entry(0)) + "\n" + tail).unwrap();
            let c = read_manifest(&path).unwrap();
            assert_eq!(c.entries, vec![entry(0)]);
            assert_eq!(c.unfinished_bytes, tail.len() as u64);
        }
    }

    #[test]
    fn a_malformed_finished_line_names_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("manifest.jsonl");
        std::fs::write(&path, line(&entry(0)) + "\n{\"id\": \"x\"}\n").unwrap();
        let e = read_manifest(&path).unwrap_err().to_string();
        assert!(
            e.contains("manifest.jsonl") && e.contains("line 3") && e.contains("missing field"),
            "{e}"
        );
    }

    #[test]
    fn open_cuts_a_torn_append_and_appends_after_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("manifest.jsonl");
        let torn = line(&entry(1));
        std::fs::write(&path, line(&entry(0)) + &torn[..20]).unwrap();
        let (mut m, done) = Manifest::open(&path).unwrap();
        assert_eq!((done.entries.len(), done.unfinished_bytes), (1, 20));
        m.append(&entry(2)).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            line(&entry(0)) + &line(&entry(2))
        );
        assert_eq!(Manifest::read(&path).unwrap(), vec![entry(0), entry(2)]);
    }

    #[test]
    fn a_line_from_before_render_timings_reads_and_empty_timings_are_not_written() {
        let mut e = entry(0);
        e.render_timings.clear();
        let text = serde_json::to_string(&e).unwrap();
        assert!(!text.contains("render_timings"), "{text}");
        assert_eq!(serde_json::from_str::<ManifestEntry>(&text).unwrap(), e);
    }
}
