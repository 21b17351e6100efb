//! The object pass: every SceneSpec's content-object targets (the object-level sample of the
//! disparity law), by category.

use std::path::Path;

use rayon::prelude::*;

use super::files::FileError;
use super::load::Loaded;

/// The object-level sample per category, and the scene files that could not be read.
pub struct ObjectPass {
    pub targets: Vec<Vec<f64>>,
    pub errors: Vec<FileError>,
}

pub fn object_pass(root: &Path, loaded: &Loaded) -> ObjectPass {
    let read: Vec<Result<(usize, Vec<f64>), FileError>> = loaded
        .entries
        .par_iter()
        .map(|e| {
            let path = root.join(&e.files.scene);
            let bytes = std::fs::read(&path)
                .map_err(|err| FileError::Io(stereo_io::Error::io(&path, err)))?;
            let spec = crate::dataset::scene_file::decode_scene_spec(&bytes).map_err(|err| {
                FileError::NotASceneSpec {
                    path,
                    message: format!("{err:#}"),
                }
            })?;
            Ok((loaded.category_of(e), spec.target_disparities().collect()))
        })
        .collect();
    let mut pass = ObjectPass {
        targets: vec![Vec::new(); loaded.categories.len()],
        errors: Vec::new(),
    };
    for r in read {
        match r {
            Ok((c, t)) => pass.targets[c].extend(t),
            Err(e) => pass.errors.push(e),
        }
    }
    pass
}
