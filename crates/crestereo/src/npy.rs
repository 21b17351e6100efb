//! Small `.npy` / `.npz` readers (float32 / float64 / bool arrays) for fixtures.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use anyhow::{Context, Result, bail};

/// An array as float32 values (row-major) with its shape.
#[derive(Debug, Clone)]
pub struct Array {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

fn convert<R: std::io::Read>(npy: npyz::NpyFile<R>) -> Result<Array> {
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    if npy.order() != npyz::Order::C {
        bail!("Fortran-order arrays are not supported");
    }
    let dtype = npy.dtype();
    let data: Vec<f32> = match &dtype {
        npyz::DType::Plain(ts) => match (ts.type_char(), ts.size_field()) {
            (npyz::TypeChar::Float, 4) => npy.into_vec::<f32>()?,
            (npyz::TypeChar::Float, 8) => npy
                .into_vec::<f64>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
            (npyz::TypeChar::Bool, 1) => npy
                .into_vec::<bool>()?
                .into_iter()
                .map(|v| v as u8 as f32)
                .collect(),
            (npyz::TypeChar::Int, 8) => npy
                .into_vec::<i64>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
            (npyz::TypeChar::Int, 4) => npy
                .into_vec::<i32>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
            (npyz::TypeChar::Uint, 1) => npy
                .into_vec::<u8>()?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
            _ => bail!("unsupported npy dtype {dtype:?}"),
        },
        _ => bail!("unsupported npy dtype {dtype:?}"),
    };
    Ok(Array { shape, data })
}

/// Reads a `.npy` file.
pub fn read_npy(path: impl AsRef<Path>) -> Result<Array> {
    let path = path.as_ref();
    let file = File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let npy = npyz::NpyFile::new(BufReader::new(file))
        .with_context(|| format!("parsing {}", path.display()))?;
    convert(npy).with_context(|| format!("reading {}", path.display()))
}

/// Reads every array of a `.npz` file (names without the `.npy` suffix).
pub fn read_npz(path: impl AsRef<Path>) -> Result<Vec<(String, Array)>> {
    let path = path.as_ref();
    let mut npz =
        npyz::npz::NpzArchive::open(path).with_context(|| format!("opening {}", path.display()))?;
    let names: Vec<String> = npz.array_names().map(|s| s.to_string()).collect();
    let mut out = Vec::new();
    for name in names {
        let npy = npz
            .by_name(&name)?
            .with_context(|| format!("{name} missing in {}", path.display()))?;
        out.push((
            name.clone(),
            convert(npy).with_context(|| format!("{name} in {}", path.display()))?,
        ));
    }
    Ok(out)
}
