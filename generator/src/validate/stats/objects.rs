//! The object pass: every SceneSpec's content-object targets (the object-level sample of the
//! disparity law), by category. A WebDataset export without SceneSpecs has no such sample.

use rayon::prelude::*;

use super::files::FileError;
use super::load::Loaded;

/// The object-level sample per category, and the scene files that could not be read.
pub struct ObjectPass {
    pub targets: Vec<Vec<f64>>,
    pub errors: Vec<FileError>,
}

impl ObjectPass {
    /// No objects: the pass that is not run (an export without SceneSpecs).
    pub fn empty(categories: usize) -> Self {
        Self {
            targets: vec![Vec::new(); categories],
            errors: Vec::new(),
        }
    }
}

pub fn object_pass(loaded: &Loaded) -> ObjectPass {
    let read: Vec<Result<(usize, Vec<f64>), FileError>> = loaded
        .entries
        .par_iter()
        .map(|e| {
            let bytes = loaded.files.read(e, "scene").map_err(FileError::Io)?;
            let spec = crate::dataset::scene_file::decode_scene_spec(&bytes).map_err(|err| {
                FileError::NotASceneSpec {
                    path: loaded.files.path(e, "scene"),
                    message: format!("{err:#}"),
                }
            })?;
            Ok((loaded.category_of(e), spec.target_disparities().collect()))
        })
        .collect();
    let mut pass = ObjectPass::empty(loaded.categories.len());
    for r in read {
        match r {
            Ok((c, t)) => pass.targets[c].extend(t),
            Err(e) => pass.errors.push(e),
        }
    }
    pass
}
