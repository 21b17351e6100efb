//! NVIDIA Falling Things: `*.left.jpg`, `*.right.jpg`, `*.left.depth.png` (16-bit depth in
//! 1e-4 m) beside each folder's `_camera_settings.json`; disparity = fx · 0.06 m / Z.

use std::path::Path;

use super::scan::{file_name, rel_id, require, walk};
use super::{DispKind, SampleFiles, SampleMeta};
use crate::error::{Error, Result};

/// The file that makes a folder a Falling Things folder.
pub const CAMERA_SETTINGS: &str = "_camera_settings.json";

/// The cameras of Falling Things are 6 cm apart.
pub const FALLING_THINGS_BASELINE_M: f64 = 0.06;

fn fat_fx(path: &Path) -> Result<(f64, Option<f64>, Option<f64>)> {
    let text = crate::limits::read_document(path, "a camera settings file")?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::format(path, format!("not JSON: {e}")))?;
    let intr = &v["camera_settings"][0]["intrinsic_settings"];
    let fx = intr["fx"]
        .as_f64()
        .ok_or_else(|| Error::format(path, "no camera_settings[0].intrinsic_settings.fx"))?;
    Ok((fx, intr["cx"].as_f64(), intr["cy"].as_f64()))
}

pub(crate) fn scan(root: &Path) -> Result<Vec<SampleFiles>> {
    let mut out = Vec::new();
    for settings in walk(root, 6).filter(|e| file_name(e.path()) == CAMERA_SETTINGS) {
        let dir = settings.path().parent().unwrap_or(root);
        let (fx, cx, cy) = fat_fx(settings.path())?;
        let kind = DispKind::FatDepth {
            fx,
            baseline_m: FALLING_THINGS_BASELINE_M,
        };
        for e in walk(dir, 1) {
            let name = file_name(e.path());
            let Some(stem) = name.strip_suffix(".left.jpg") else {
                continue;
            };
            let right = require(
                dir.join(format!("{stem}.right.jpg")),
                "right image",
                e.path(),
            )?;
            let depth = require(
                dir.join(format!("{stem}.left.depth.png")),
                "left depth",
                e.path(),
            )?;
            let depth_r = dir.join(format!("{stem}.right.depth.png"));
            out.push(SampleFiles {
                id: rel_id(root, &dir.join(stem)),
                left: e.path().to_path_buf(),
                right,
                disp_left: (depth, kind),
                disp_right: depth_r.is_file().then_some((depth_r, kind)),
                masks: vec![],
                meta: SampleMeta {
                    f_px: Some(fx),
                    baseline_m: Some(FALLING_THINGS_BASELINE_M),
                    cx,
                    cy,
                    ..Default::default()
                },
            });
        }
    }
    Ok(out)
}
