//! Where each file of a dataset lives: stereo-io's layout of our datasets
//! ([`stereo_io::datasets::stereogen`]), with what only the generator does with a dataset directory.

use anyhow::{Context, bail};

use stereo_io::ManifestEntry;
pub use stereo_io::{DatasetLayout, SamplePaths};

use crate::plan::Recipe;

/// `entry` with its files' paths put under `prefix` (a folder inside the dataset): how a
/// top-level manifest names the files of a farm's shard or of a curation round.
pub fn entry_under(prefix: &std::path::Path, mut entry: ManifestEntry) -> ManifestEntry {
    for p in entry.files.all_mut() {
        *p = prefix.join(&*p);
    }
    entry
}

/// `dataset.json` with the recipe read as the generator's [`Recipe`].
pub type DatasetInfo = stereo_io::DatasetInfo<Recipe>;

/// The class table of the semantic maps, for a recipe that writes them (none otherwise).
pub fn semantic_classes(recipe: &Recipe) -> Vec<stereo_io::datasets::stereogen::SemanticClass> {
    if !recipe
        .render
        .outputs
        .contains(&crate::plan::OutputMap::Semantic)
    {
        return Vec::new();
    }
    crate::plan::SEMANTIC_CLASSES
        .iter()
        .enumerate()
        .map(|(i, name)| stereo_io::datasets::stereogen::SemanticClass {
            id: i as u16 + 1,
            name: name.to_string(),
        })
        .collect()
}

/// Opening a dataset directory to generate into it.
pub trait CreateDataset {
    /// Creates the root (and checks that it is writable), or checks that an existing dataset
    /// was made with the same recipe and seed.
    fn open_or_create(&self, recipe: &Recipe, seed: u64) -> anyhow::Result<DatasetInfo>;
    /// Records the asset index's fingerprint in `dataset.json`, or refuses a dataset whose
    /// samples were planned from other assets (the content pack or an asset folder changed).
    fn check_assets(&self, fingerprint: Option<&str>) -> anyhow::Result<()>;
}

impl CreateDataset for DatasetLayout {
    fn open_or_create(&self, recipe: &Recipe, seed: u64) -> anyhow::Result<DatasetInfo> {
        std::fs::create_dir_all(&self.root)
            .with_context(|| format!("cannot create output directory {}", self.root.display()))?;
        tempfile::tempfile_in(&self.root)
            .with_context(|| format!("output directory {} is not writable", self.root.display()))?;
        let info = DatasetInfo {
            stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
            seed,
            recipe_fingerprint: recipe.fingerprint(),
            recipe: recipe.clone(),
            assets_fingerprint: None,
            curation: Vec::new(),
            semantic_classes: semantic_classes(recipe),
        };
        if self.info().exists() {
            let existing: DatasetInfo = self.read_info()?;
            if existing.seed != seed {
                bail!(
                    "{} was generated with --seed {}; resume with that seed or choose another --out",
                    self.root.display(),
                    existing.seed
                );
            }
            if existing.recipe_fingerprint != info.recipe_fingerprint {
                bail!(
                    "{} was generated with another recipe ({}, fingerprint {}); resume with that recipe or choose another --out",
                    self.root.display(),
                    existing.recipe.name,
                    existing.recipe_fingerprint
                );
            }
            return Ok(existing);
        }
        self.write_info(&info)?;
        Ok(info)
    }

    fn check_assets(&self, fingerprint: Option<&str>) -> anyhow::Result<()> {
        let mut info: DatasetInfo = self.read_info()?;
        match (&info.assets_fingerprint, fingerprint) {
            (Some(had), Some(now)) if had == now => Ok(()),
            (Some(had), now) => bail!(
                "{} was generated from other assets (fingerprint {had}, now {}): the content pack or an asset folder changed; restore them or choose another --out",
                self.root.display(),
                now.unwrap_or("none")
            ),
            // Datasets made before the fingerprint was recorded adopt the current one.
            (None, Some(now)) => {
                info.assets_fingerprint = Some(now.to_string());
                Ok(self.write_info(&info)?)
            }
            (None, None) => Ok(()),
        }
    }
}
