//! InStereo2K (indoor, structured light): one folder per pair, `left.png`, `right.png`,
//! `left_disp.png`, `right_disp.png`, under `train/` and `test/` (the archive adds `partN/`
//! levels). Its readme: disparity is stored as a 16-bit PNG of `round(d · 100)`, 0 = invalid.

use std::path::Path;

use super::scan::{file_name, rel_id, require, walk};
use super::{DispKind, SampleFiles, SampleMeta};
use crate::error::Result;

pub const LEFT_IMAGE: &str = "left.png";
pub const RIGHT_IMAGE: &str = "right.png";
/// What names a sample's folder; also how the layout is recognised.
pub const LEFT_DISPARITY: &str = "left_disp.png";
pub const RIGHT_DISPARITY: &str = "right_disp.png";
/// The fixed-point scale of its disparity PNGs.
pub const DISPARITY_SCALE: f32 = 100.0;

pub(crate) fn scan(root: &Path) -> Result<Vec<SampleFiles>> {
    let mut out = Vec::new();
    for e in walk(root, 6) {
        if file_name(e.path()) != LEFT_DISPARITY {
            continue;
        }
        let dir = e.path().parent().unwrap_or(root);
        let left = require(dir.join(LEFT_IMAGE), "left image left.png", dir)?;
        let right = require(dir.join(RIGHT_IMAGE), "right image right.png", dir)?;
        let disp_right = dir.join(RIGHT_DISPARITY);
        out.push(SampleFiles {
            id: rel_id(root, dir),
            left,
            right,
            disp_left: (e.path().to_path_buf(), DispKind::Png16(DISPARITY_SCALE)),
            disp_right: disp_right
                .is_file()
                .then_some((disp_right, DispKind::Png16(DISPARITY_SCALE))),
            masks: vec![],
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}
