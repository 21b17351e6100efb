//! The `stereogen._stereogen` extension of the Python package `stereogen` (its Python part, with
//! `stereogen.torch`, is under `python/`): stereo datasets as NumPy arrays, disparity files, a dataset's
//! sidecar logs (`failures.jsonl`, `skipped_assets.jsonl`), and scene
//! planning — the same Rust code the generator and trainer use.
//!
//! Decoding runs with the GIL released; pixel buffers are handed to NumPy without copying.

use std::path::PathBuf;

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyIndexError, PyOSError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};
use stereo_io::datasets::SampleMaps;
use stereo_io::{
    DatasetFormat, DisparityFormat, DisparityMap, DisparityMeta, StereoDataset, StereoSample,
};

/// Rust errors become Python exceptions carrying the same message: `OSError` for I/O,
/// `ValueError` for malformed files and bad arguments.
fn to_py(e: stereo_io::Error) -> PyErr {
    match e {
        stereo_io::Error::Io { .. } => PyOSError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

fn array_hw<'py, T: numpy::Element>(
    py: Python<'py>,
    data: Vec<T>,
    h: usize,
    w: usize,
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, data).reshape([h, w])?.into_any())
}

fn rgb_array<'py>(py: Python<'py>, img: stereo_io::RgbImage) -> PyResult<Bound<'py, PyAny>> {
    let (h, w) = (img.height, img.width);
    Ok(PyArray1::from_vec(py, img.data)
        .reshape([h, w, 3])?
        .into_any())
}

fn parse_disp_format(format: Option<&str>) -> PyResult<Option<DisparityFormat>> {
    format
        .map(|f| f.parse::<DisparityFormat>().map_err(PyValueError::new_err))
        .transpose()
}

fn meta_dict<'py>(py: Python<'py>, s: &StereoSample) -> PyResult<Bound<'py, PyDict>> {
    let m = &s.meta;
    let d = PyDict::new(py);
    d.set_item("id", &m.id)?;
    d.set_item("format", m.format.map(|f| f.name()))?;
    d.set_item("left_path", m.left_path.to_string_lossy())?;
    d.set_item("right_path", m.right_path.to_string_lossy())?;
    d.set_item("disp_left_path", m.disp_left_path.to_string_lossy())?;
    d.set_item("f_px", m.f_px)?;
    d.set_item("baseline_m", m.baseline_m)?;
    d.set_item("cx", m.cx)?;
    d.set_item("cy", m.cy)?;
    d.set_item("ndisp", m.ndisp)?;
    let extra = PyDict::new(py);
    for (k, v) in &m.extra {
        extra.set_item(k, v)?;
    }
    d.set_item("extra", extra)?;
    Ok(d)
}

/// JSON text as Python objects (`json.loads`).
fn from_json<'py>(py: Python<'py>, json: String) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (json,))
}

/// The maps of a sample as entries of its dict: `depth_<view>` (float32 H×W, metres, 0 = no
/// surface), `normals_<view>` (float32 H×W×3, camera frame x right, y down, z forward),
/// `instance_<view>`, `semantic_<view>` (uint16 H×W, 0 = no surface), each where the sample has
/// it; and `instances`, its instance table (list of dicts), where it has one.
fn add_maps<'py>(
    py: Python<'py>,
    d: &Bound<'py, PyDict>,
    maps: SampleMaps,
    s: &StereoSample,
) -> PyResult<()> {
    for (view, m) in [("left", maps.left), ("right", maps.right)] {
        if let Some(m) = m.depth {
            d.set_item(
                format!("depth_{view}"),
                array_hw(py, m.data, m.height, m.width)?,
            )?;
        }
        if let Some(m) = m.normals {
            let flat: Vec<f32> = m.data.into_iter().flatten().collect();
            let a = PyArray1::from_vec(py, flat).reshape([m.height, m.width, 3])?;
            d.set_item(format!("normals_{view}"), a)?;
        }
        for (kind, ids) in [("instance", m.instance), ("semantic", m.semantic)] {
            if let Some(ids) = ids {
                let a = array_hw(py, ids.data, ids.height, ids.width)?;
                d.set_item(format!("{kind}_{view}"), a)?;
            }
        }
    }
    if !s.meta.instances.is_empty() {
        let json = serde_json::to_string(&s.meta.instances)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        d.set_item("instances", from_json(py, json)?)?;
    }
    Ok(())
}

fn sample_dict<'py>(
    py: Python<'py>,
    s: StereoSample,
    maps: SampleMaps,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("meta", meta_dict(py, &s)?)?;
    add_maps(py, &d, maps, &s)?;
    let (h, w) = (s.disp_left.height, s.disp_left.width);
    let valid = s.valid_mask().to_vec();
    d.set_item("valid_left", array_hw(py, valid, h, w)?)?;
    d.set_item("disp_left", array_hw(py, s.disp_left.data, h, w)?)?;
    match s.disp_right {
        Some(r) => {
            d.set_item("valid_right", array_hw(py, r.valid, h, w)?)?;
            d.set_item("disp_right", array_hw(py, r.data, h, w)?)?;
        }
        None => {
            d.set_item("valid_right", py.None())?;
            d.set_item("disp_right", py.None())?;
        }
    }
    d.set_item("left", rgb_array(py, s.left)?)?;
    d.set_item("right", rgb_array(py, s.right)?)?;
    Ok(d)
}

/// A stereo dataset: `len(ds)`, `ds[i]` → dict with `left`, `right` (uint8 H×W×3), `disp_left`
/// (float32 H×W, 0 where invalid), `valid_left` (bool H×W), `disp_right`/`valid_right` (or
/// None) and `meta` (dict); where the sample has maps beside its disparity, also `depth_left`,
/// `depth_right` (float32 H×W, metres along the optical axis, 0 = no surface), `normals_left`,
/// `normals_right` (float32 H×W×3, unit normals in the camera frame: x right, y down, z
/// forward; 0 = no surface), `instance_left`, ..., `semantic_right` (uint16 H×W ids, 0 = no
/// surface) and `instances` (the instance table: list of dicts with id, name, role, source,
/// mesh, material, semantic).
#[pyclass(name = "Dataset", module = "stereogen", frozen)]
struct Dataset {
    inner: Box<dyn StereoDataset>,
}

#[pymethods]
impl Dataset {
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __getitem__<'py>(&self, py: Python<'py>, index: isize) -> PyResult<Bound<'py, PyDict>> {
        let n = self.inner.len() as isize;
        let i = if index < 0 { index + n } else { index };
        if i < 0 || i >= n {
            return Err(PyIndexError::new_err(format!(
                "index {index} is out of range for a dataset of {n} samples"
            )));
        }
        let inner = &self.inner;
        let (sample, maps) = py
            .detach(|| {
                Ok::<_, stereo_io::Error>((inner.sample(i as usize)?, inner.maps(i as usize)?))
            })
            .map_err(to_py)?;
        sample_dict(py, sample, maps)
    }

    /// The classes of the `semantic_*` maps as {id: name} (from the `dataset.json` of ours or
    /// of its WebDataset export); empty where the dataset has none.
    #[getter]
    fn semantic_classes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let layout = stereo_io::DatasetLayout::new(self.inner.root());
        let d = PyDict::new(py);
        if layout.info().is_file() {
            let info = py
                .detach(|| layout.read_info::<serde_json::Value>())
                .map_err(to_py)?;
            for c in info.semantic_classes {
                d.set_item(c.id, c.name)?;
            }
        }
        Ok(d)
    }

    /// The layout name (stereogen, crestereo, sceneflow, middlebury, eth3d, kitti2012, kitti2015, sintel, fallingthings, webdataset).
    #[getter]
    fn format(&self) -> &'static str {
        self.inner.format().name()
    }

    #[getter]
    fn root(&self) -> String {
        self.inner.root().to_string_lossy().into_owned()
    }

    /// The stable name of sample `index`, without decoding it.
    fn id(&self, index: usize) -> PyResult<String> {
        self.inner
            .id(index)
            .map(str::to_owned)
            .ok_or_else(|| PyIndexError::new_err(format!("index {index} is out of range")))
    }

    fn __repr__(&self) -> String {
        format!(
            "stereogen.Dataset(format={:?}, root={:?}, len={})",
            self.inner.format().name(),
            self.inner.root(),
            self.inner.len()
        )
    }
}

/// open_dataset(path, format=None) -> Dataset
///
/// Opens a stereo dataset folder. Without `format` the layout is recognised from the folder; a
/// WebDataset export (`stereogen export --format webdataset`) is read from its tar shards in place.
#[pyfunction]
#[pyo3(signature = (path, format=None))]
fn open_dataset(py: Python<'_>, path: PathBuf, format: Option<&str>) -> PyResult<Dataset> {
    let format = format
        .map(|f| f.parse::<DatasetFormat>().map_err(PyValueError::new_err))
        .transpose()?;
    let inner = py
        .detach(|| stereo_io::open_dataset(&path, format))
        .map_err(to_py)?;
    Ok(Dataset { inner })
}

/// detect_format(path) -> str: the layout name `open_dataset` would use.
#[pyfunction]
fn detect_format(py: Python<'_>, path: PathBuf) -> PyResult<&'static str> {
    py.detach(|| stereo_io::detect_format(&path))
        .map(|f| f.name())
        .map_err(to_py)
}

/// read_disparity(path, format=None, with_meta=False) -> (disparity, valid) or (disparity, valid, meta)
///
/// `disparity` is float32 H×W holding 0 where `valid` (bool H×W) is False. The format comes from
/// the name (.exr, .pfm, .npy, *.disp.png = ×32, other .png = ×256) or `format` (exr, pfm, npy,
/// sintel, png32, png256, png16:SCALE). `meta` (EXR only) has f_px, baseline_m, view.
#[pyfunction]
#[pyo3(signature = (path, format=None, with_meta=false))]
fn read_disparity<'py>(
    py: Python<'py>,
    path: PathBuf,
    format: Option<&str>,
    with_meta: bool,
) -> PyResult<Bound<'py, PyTuple>> {
    let format = parse_disp_format(format)?;
    let (map, meta) = py
        .detach(|| stereo_io::read_disparity(&path, format))
        .map_err(to_py)?;
    disparity_tuple(py, map, meta, with_meta)
}

/// write_disparity(path, array, f_px=None, baseline=None, valid=None, format=None, view=None)
///
/// Writes a H×W disparity array (any float dtype; converted to float32). `valid` defaults to the
/// finite pixels. The file appears atomically. `f_px`, `baseline` (metres) and `view` are stored
/// in EXR headers only.
#[pyfunction]
#[pyo3(signature = (path, array, f_px=None, baseline=None, valid=None, format=None, view=None))]
#[allow(clippy::too_many_arguments)]
fn write_disparity(
    py: Python<'_>,
    path: PathBuf,
    array: &Bound<'_, PyAny>,
    f_px: Option<f64>,
    baseline: Option<f64>,
    valid: Option<&Bound<'_, PyAny>>,
    format: Option<&str>,
    view: Option<String>,
) -> PyResult<()> {
    let np = py.import("numpy")?;
    let arr = np
        .call_method1("ascontiguousarray", (array, "float32"))?
        .cast_into::<numpy::PyArrayDyn<f32>>()?;
    let shape = arr.shape().to_vec();
    let [h, w] = shape[..] else {
        return Err(PyValueError::new_err(format!(
            "{}: a disparity array must be 2-D (H, W), got shape {shape:?}",
            path.display()
        )));
    };
    let data: Vec<f32> = arr.readonly().as_slice()?.to_vec();
    let valid: Vec<bool> = match valid {
        Some(v) => {
            let v = np
                .call_method1("ascontiguousarray", (v, "bool"))?
                .cast_into::<numpy::PyArrayDyn<bool>>()?;
            if v.shape() != [h, w] {
                return Err(PyValueError::new_err(format!(
                    "{}: valid has shape {:?}, the disparity {shape:?}",
                    path.display(),
                    v.shape()
                )));
            }
            v.readonly().as_slice()?.to_vec()
        }
        None => data.iter().map(|d| d.is_finite()).collect(),
    };
    let data = data
        .iter()
        .zip(&valid)
        .map(|(&d, &v)| if v && d.is_finite() { d } else { 0.0 })
        .collect();
    let map = DisparityMap {
        width: w,
        height: h,
        data,
        valid,
    };
    let meta = DisparityMeta {
        f_px,
        baseline_m: baseline,
        view,
    };
    let format = parse_disp_format(format)?;
    py.detach(|| stereo_io::write_disparity(&path, &map, &meta, format))
        .map_err(to_py)
}

/// decode_sample(members, key=None) -> dict
///
/// Decodes one sample of a WebDataset shard from its members, as the `webdataset` package hands
/// them over: a dict of member name after the key (`left.png`, `disp_left.exr`, `json`, ...) to
/// bytes; entries whose name starts with `__` (`__key__`, `__url__`) are ignored, and `json` may
/// also be an already decoded dict. Returns what `Dataset[i]` returns for that sample, bit for bit
/// (its maps, `depth_left` ..., from the members `depth_left.exr` ..., where it has them).
#[pyfunction]
#[pyo3(signature = (members, key=None))]
fn decode_sample<'py>(
    py: Python<'py>,
    members: &Bound<'py, PyDict>,
    key: Option<String>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut list: Vec<(String, Vec<u8>)> = Vec::with_capacity(members.len());
    let mut url = None;
    let mut found_key = None;
    for (name, value) in members.iter() {
        let name: String = name.extract()?;
        match name.as_str() {
            "__key__" => found_key = value.extract::<String>().ok(),
            "__url__" => url = value.extract::<String>().ok(),
            _ if name.starts_with("__") => {}
            _ => {
                let bytes = if let Ok(b) = value.cast::<PyBytes>() {
                    b.as_bytes().to_vec()
                } else if name == "json" {
                    let text: String = py
                        .import("json")?
                        .call_method1("dumps", (value,))?
                        .extract()?;
                    text.into_bytes()
                } else {
                    return Err(PyTypeError::new_err(format!(
                        "member {name:?}: bytes expected, got {}",
                        value.get_type().name()?
                    )));
                };
                list.push((name, bytes));
            }
        }
    }
    let key = key.or(found_key).unwrap_or_default();
    let shard = PathBuf::from(url.unwrap_or_default());
    let (sample, maps) = py
        .detach(|| {
            use stereo_io::datasets::webdataset::{decode_member_maps, decode_members};
            Ok::<_, stereo_io::Error>((
                decode_members(&shard, &key, &list)?,
                decode_member_maps(&shard, &key, &list)?,
            ))
        })
        .map_err(to_py)?;
    sample_dict(py, sample, maps)
}

/// decode_disparity(data, with_meta=False) -> (disparity, valid) or (disparity, valid, meta)
///
/// A disparity EXR of ours (a `disp_left.exr` member of a shard, say) decoded from its bytes, as
/// `read_disparity` decodes the file.
#[pyfunction]
#[pyo3(signature = (data, with_meta=false))]
fn decode_disparity<'py>(
    py: Python<'py>,
    data: &[u8],
    with_meta: bool,
) -> PyResult<Bound<'py, PyTuple>> {
    let (map, meta) = py
        .detach(|| stereo_io::decode_disparity_exr(data, std::path::Path::new("<bytes>")))
        .map_err(to_py)?;
    disparity_tuple(py, map, meta, with_meta)
}

fn disparity_tuple<'py>(
    py: Python<'py>,
    map: DisparityMap,
    meta: DisparityMeta,
    with_meta: bool,
) -> PyResult<Bound<'py, PyTuple>> {
    let (h, w) = (map.height, map.width);
    let disp = array_hw(py, map.data, h, w)?;
    let valid = array_hw(py, map.valid, h, w)?;
    if with_meta {
        let m = PyDict::new(py);
        m.set_item("f_px", meta.f_px)?;
        m.set_item("baseline_m", meta.baseline_m)?;
        m.set_item("view", meta.view)?;
        PyTuple::new(py, [disp, valid, m.into_any()])
    } else {
        PyTuple::new(py, [disp, valid])
    }
}

/// Records of a sidecar log as a list of dicts (the fields of the Rust record type, through JSON).
fn sidecar_records<'py, R: stereo_io::datasets::stereogen::SidecarRecord + Send>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<Bound<'py, PyAny>> {
    let json = py
        .detach(|| {
            let records = stereo_io::datasets::stereogen::read_sidecar::<R>(&path)?.records;
            serde_json::to_string(&records)
                .map_err(|e| stereo_io::Error::format(&path, e.to_string()))
        })
        .map_err(to_py)?;
    py.import("json")?.call_method1("loads", (json,))
}

/// read_failures(path) -> list[dict]
///
/// The finished records of a dataset's `failures.jsonl` (version, index, error, traceback when
/// the worker sent one), read by the Rust reader `generate` and `merge` use; a missing file has
/// none. A malformed or newer-version line raises ValueError naming the file and line.
#[pyfunction]
fn read_failures<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyAny>> {
    sidecar_records::<stereo_io::datasets::stereogen::FailureRecord>(py, path)
}

/// read_skipped_assets(path) -> list[dict]
///
/// The finished records of a dataset's `skipped_assets.jsonl` (version, path, reason, sample:
/// the index whose worker refused it, or None), like [`read_failures`].
#[pyfunction]
fn read_skipped_assets<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyAny>> {
    sidecar_records::<stereo_io::datasets::stereogen::SkippedAssetRecord>(py, path)
}

/// plan_scene(recipe, seed, index) -> dict
///
/// The SceneSpec of sample `index` of (`recipe`, `seed`), planned by the generator's own Rust
/// planner. `recipe` is a preset name or a recipe TOML path.
#[pyfunction]
fn plan_scene<'py>(
    py: Python<'py>,
    recipe: &str,
    seed: u64,
    index: u64,
) -> PyResult<Bound<'py, PyAny>> {
    let json = py
        .detach(|| -> anyhow_free::Result<String> {
            let recipe =
                stereogen_plan::Recipe::load_or_preset(recipe).map_err(|e| e.to_string())?;
            let home = stereogen_assets::stereogen_home();
            let assets = stereogen_assets::index_sources(&recipe.sources, &home)
                .map_err(|e| format!("{e:#}"))?;
            Ok(stereogen_plan::plan_scene(&recipe, &assets, seed, index).to_json())
        })
        .map_err(PyValueError::new_err)?;
    py.import("json")?.call_method1("loads", (json,))
}

mod anyhow_free {
    pub type Result<T> = std::result::Result<T, String>;
}

#[pymodule(name = "_stereogen")]
fn stereogen_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Dataset>()?;
    m.add_function(wrap_pyfunction!(open_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(detect_format, m)?)?;
    m.add_function(wrap_pyfunction!(read_disparity, m)?)?;
    m.add_function(wrap_pyfunction!(decode_disparity, m)?)?;
    m.add_function(wrap_pyfunction!(decode_sample, m)?)?;
    m.add_function(wrap_pyfunction!(write_disparity, m)?)?;
    m.add_function(wrap_pyfunction!(plan_scene, m)?)?;
    m.add_function(wrap_pyfunction!(read_failures, m)?)?;
    m.add_function(wrap_pyfunction!(read_skipped_assets, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
