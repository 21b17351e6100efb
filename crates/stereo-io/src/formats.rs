//! One entry point for disparity files of any supported format.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use crate::disparity::{DisparityMap, DisparityMeta};
use crate::error::{Error, Result};

/// A disparity file format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DisparityFormat {
    /// Float32 EXR, channel `Y` + `valid` and camera attributes (ours).
    Exr,
    /// 1-channel PFM, `inf` = invalid (SceneFlow, Middlebury, ETH3D).
    Pfm,
    /// 16-bit grey PNG, `d = value / scale`, 0 = invalid (CREStereo ×32, KITTI ×256).
    Png16 { scale: f32 },
    /// Sintel's RGB-packed PNG.
    SintelPng,
    /// NumPy float array (H, W), `inf` = invalid.
    Npy,
}

impl DisparityFormat {
    /// Guesses from the file name: `.exr`, `.pfm`, `.npy`; `*.disp.png` is CREStereo's ×32 and any
    /// other `.png` KITTI's ×256 (16-bit) — pass the format explicitly for Sintel.
    pub fn from_path(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        let ext = name.rsplit('.').next()?;
        Some(match ext {
            "exr" => Self::Exr,
            "pfm" => Self::Pfm,
            "npy" => Self::Npy,
            "png" if name.ends_with(".disp.png") => Self::Png16 {
                scale: crate::png_disp::CRESTEREO_SCALE,
            },
            "png" => Self::Png16 {
                scale: crate::png_disp::KITTI_SCALE,
            },
            _ => return None,
        })
    }
}

impl fmt::Display for DisparityFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Exr => write!(f, "exr"),
            Self::Pfm => write!(f, "pfm"),
            Self::Png16 { scale } if *scale == 32.0 => write!(f, "png32"),
            Self::Png16 { scale } if *scale == 256.0 => write!(f, "png256"),
            Self::Png16 { scale } => write!(f, "png16:{scale}"),
            Self::SintelPng => write!(f, "sintel"),
            Self::Npy => write!(f, "npy"),
        }
    }
}

impl FromStr for DisparityFormat {
    type Err = String;
    /// `exr`, `pfm`, `npy`, `sintel`, `png32` (or `crestereo`), `png256` (or `kitti`), `png16:SCALE`.
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "exr" => Self::Exr,
            "pfm" => Self::Pfm,
            "npy" => Self::Npy,
            "sintel" => Self::SintelPng,
            "png32" | "crestereo" => Self::Png16 { scale: 32.0 },
            "png256" | "kitti" => Self::Png16 { scale: 256.0 },
            other => match other
                .strip_prefix("png16:")
                .and_then(|v| v.parse::<f32>().ok())
            {
                Some(scale) if scale.is_finite() && scale > 0.0 => Self::Png16 { scale },
                _ => {
                    return Err(format!(
                        "unknown disparity format {s:?} (exr, pfm, npy, sintel, png32, png256, png16:SCALE)"
                    ));
                }
            },
        })
    }
}

fn resolve(path: &Path, format: Option<DisparityFormat>) -> Result<DisparityFormat> {
    format.or_else(|| DisparityFormat::from_path(path)).ok_or_else(|| Error::format(path, "cannot tell the disparity format from the file name (.exr, .pfm, .png, .npy); give it explicitly"))
}

/// Reads a disparity file; the format comes from `format` or the file name.
pub fn read_disparity(
    path: &Path,
    format: Option<DisparityFormat>,
) -> Result<(DisparityMap, DisparityMeta)> {
    let map = match resolve(path, format)? {
        DisparityFormat::Exr => return crate::exr_io::read_disparity_exr(path),
        DisparityFormat::Pfm => crate::pfm::read_disparity_pfm(path)?,
        DisparityFormat::Png16 { scale } => crate::png_disp::read_disparity_png16(path, scale)?,
        DisparityFormat::SintelPng => crate::png_disp::read_disparity_sintel(path)?,
        DisparityFormat::Npy => crate::npy::read_disparity_npy(path)?,
    };
    Ok((map, DisparityMeta::default()))
}

/// Writes a disparity file atomically; only EXR keeps `meta`.
pub fn write_disparity(
    path: &Path,
    map: &DisparityMap,
    meta: &DisparityMeta,
    format: Option<DisparityFormat>,
) -> Result<()> {
    match resolve(path, format)? {
        DisparityFormat::Exr => crate::exr_io::write_disparity_exr(path, map, meta),
        DisparityFormat::Pfm => crate::pfm::write_disparity_pfm(path, map),
        DisparityFormat::Png16 { scale } => {
            crate::png_disp::write_disparity_png16(path, map, scale)
        }
        DisparityFormat::SintelPng => crate::png_disp::write_disparity_sintel(path, map),
        DisparityFormat::Npy => crate::npy::write_disparity_npy(path, map),
    }
}
