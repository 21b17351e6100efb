//! Where each file of a dataset lives: stereo-io's layout of our datasets
//! ([`stereo_io::datasets::stereogen`]), with what only the generator does with a dataset directory.

use anyhow::{Context, bail};

pub use stereo_io::{DatasetLayout, SamplePaths};

use crate::plan::Recipe;

/// `dataset.json` with the recipe read as the generator's [`Recipe`].
pub type DatasetInfo = stereo_io::DatasetInfo<Recipe>;

/// Opening a dataset directory to generate into it.
pub trait CreateDataset {
    /// Creates the root (and checks that it is writable), or checks that an existing dataset
    /// was made with the same recipe and seed.
    fn open_or_create(&self, recipe: &Recipe, seed: u64) -> anyhow::Result<DatasetInfo>;
}

impl CreateDataset for DatasetLayout {
    fn open_or_create(&self, recipe: &Recipe, seed: u64) -> anyhow::Result<DatasetInfo> {
        std::fs::create_dir_all(&self.root).with_context(|| format!("cannot create output directory {}", self.root.display()))?;
        tempfile::tempfile_in(&self.root).with_context(|| format!("output directory {} is not writable", self.root.display()))?;
        let info = DatasetInfo {
            stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
            seed,
            recipe_fingerprint: recipe.fingerprint(),
            recipe: recipe.clone(),
        };
        if self.info().exists() {
            let existing: DatasetInfo = self.read_info()?;
            if existing.seed != seed {
                bail!("{} was generated with --seed {}; resume with that seed or choose another --out", self.root.display(), existing.seed);
            }
            if existing.recipe_fingerprint != info.recipe_fingerprint {
                bail!("{} was generated with another recipe ({}, fingerprint {}); resume with that recipe or choose another --out", self.root.display(), existing.recipe.name, existing.recipe_fingerprint);
            }
            return Ok(existing);
        }
        self.write_info(&info)?;
        Ok(info)
    }
}
