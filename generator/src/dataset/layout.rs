//! Where each file of a dataset lives.
//!
//! ```text
//! <out>/dataset.json                   recipe, seed and version the dataset was made with
//! <out>/manifest.jsonl                 one line per finished sample (written last)
//! <out>/failures.jsonl                 samples that failed, with the reason
//! <out>/skipped_assets.jsonl           mesh/texture files that could not be used, with the reason
//! <out>/<category>/<id>_left.png       and _right.png
//! <out>/<category>/<id>_left.disp.exr  and _right.disp.exr (float32 disparity + validity)
//! <out>/<category>/<id>.scene.json     the SceneSpec that reproduces the sample
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use crate::plan::Recipe;

#[derive(Debug, Clone)]
pub struct DatasetLayout {
    pub root: PathBuf,
}

/// Paths of one sample's files, relative to the dataset root.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SamplePaths {
    pub left: PathBuf,
    pub right: PathBuf,
    pub disp_left: PathBuf,
    pub disp_right: PathBuf,
    pub scene: PathBuf,
}

impl SamplePaths {
    pub fn all(&self) -> [(&'static str, &Path); 5] {
        [("left", &self.left), ("right", &self.right), ("disp_left", &self.disp_left), ("disp_right", &self.disp_right), ("scene", &self.scene)]
    }
}

/// What a dataset directory was made with, so a resumed run cannot mix recipes or seeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetInfo {
    pub stereogen_version: String,
    pub seed: u64,
    pub recipe_fingerprint: String,
    pub recipe: Recipe,
}

impl DatasetLayout {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    pub fn manifest(&self) -> PathBuf {
        self.root.join("manifest.jsonl")
    }

    pub fn failures(&self) -> PathBuf {
        self.root.join("failures.jsonl")
    }

    pub fn skipped_assets(&self) -> PathBuf {
        self.root.join("skipped_assets.jsonl")
    }

    pub fn info(&self) -> PathBuf {
        self.root.join("dataset.json")
    }

    pub fn lock(&self) -> PathBuf {
        self.root.join(".stereogen.lock")
    }

    pub fn sample_paths(&self, category: &str, id: &str) -> SamplePaths {
        let c = PathBuf::from(category);
        SamplePaths {
            left: c.join(format!("{id}_left.png")),
            right: c.join(format!("{id}_right.png")),
            disp_left: c.join(format!("{id}_left.disp.exr")),
            disp_right: c.join(format!("{id}_right.disp.exr")),
            scene: c.join(format!("{id}.scene.json")),
        }
    }

    pub fn abs(&self, rel: &Path) -> PathBuf {
        self.root.join(rel)
    }

    /// Creates the root (and checks that it is writable), or checks that an existing dataset
    /// was made with the same recipe and seed.
    pub fn open_or_create(&self, recipe: &Recipe, seed: u64) -> anyhow::Result<DatasetInfo> {
        std::fs::create_dir_all(&self.root).with_context(|| format!("cannot create output directory {}", self.root.display()))?;
        tempfile::tempfile_in(&self.root).with_context(|| format!("output directory {} is not writable", self.root.display()))?;
        let info = DatasetInfo {
            stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
            seed,
            recipe_fingerprint: recipe.fingerprint(),
            recipe: recipe.clone(),
        };
        let path = self.info();
        if path.exists() {
            let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
            let existing: DatasetInfo = serde_json::from_str(&text).with_context(|| format!("{} is not a stereogen dataset description", path.display()))?;
            if existing.seed != seed {
                bail!("{} was generated with --seed {}; resume with that seed or choose another --out", self.root.display(), existing.seed);
            }
            if existing.recipe_fingerprint != info.recipe_fingerprint {
                bail!("{} was generated with another recipe ({}, fingerprint {}); resume with that recipe or choose another --out", self.root.display(), existing.recipe.name, existing.recipe_fingerprint);
            }
            return Ok(existing);
        }
        let json = serde_json::to_string_pretty(&info)?;
        stereo_io::write_bytes_atomically(&path, json.as_bytes())?;
        Ok(info)
    }

    /// Removes temporary files left by a run that was killed mid-write.
    pub fn remove_partial_files(&self) -> usize {
        let mut removed = 0;
        let Ok(dirs) = std::fs::read_dir(&self.root) else { return 0 };
        for dir in dirs.flatten().map(|e| e.path()).chain(std::iter::once(self.root.clone())) {
            let Ok(entries) = std::fs::read_dir(&dir) else { continue };
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with('.') && name.contains(".partial-") && std::fs::remove_file(e.path()).is_ok() {
                    removed += 1;
                }
            }
        }
        removed
    }
}
