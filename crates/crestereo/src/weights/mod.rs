//! Weight import from a reference PyTorch state dict and Burn record save/load.

mod mpk;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::module::Param;
use burn::prelude::*;
use burn::record::{FullPrecisionSettings, NamedMpkBytesRecorder, Recorder};
use burn::store::{ModuleSnapshot, PytorchStore};

use crate::network::model::CREStereo;

/// Number of parameters of the reference network.
pub const REFERENCE_PARAM_COUNT: usize = 5_432_948;

/// Outcome of a PyTorch import.
#[derive(Debug, Clone)]
pub struct ImportReport {
    /// Burn parameter paths that received a tensor.
    pub applied: Vec<String>,
    /// Burn parameter paths that found no tensor in the file.
    pub missing: Vec<String>,
    /// Tensors in the file that match no parameter (after key remapping).
    pub unused: Vec<String>,
}

impl std::fmt::Display for ImportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "applied {} tensors, missing {}, unused {}",
            self.applied.len(),
            self.missing.len(),
            self.unused.len()
        )?;
        for m in &self.missing {
            writeln!(f, "  missing: {m}")?;
        }
        for u in &self.unused {
            writeln!(f, "  unused: {u}")?;
        }
        Ok(())
    }
}

/// Reference key → Burn path renames (the reference's `nn.Sequential` indices and the
/// single-layer `LocalFeatureTransformer` wrappers).
const KEY_REMAPS: &[(&str, &str)] = &[
    (r"^(self|cross)_att_fn\.layers\.0\.", "${1}_att_fn."),
    (r"\.mlp\.0\.", ".mlp1."),
    (r"\.mlp\.2\.", ".mlp2."),
    (r"^update_block\.mask\.0\.", "update_block.mask1."),
    (r"^update_block\.mask\.2\.", "update_block.mask2."),
    (r"\.downsample\.0\.", ".downsample."),
    // LayerNorm weight/bias are Burn's gamma/beta (renamed here so the report is exact)
    (r"_att_fn\.norm([12])\.weight$", "_att_fn.norm${1}.gamma"),
    (r"_att_fn\.norm([12])\.bias$", "_att_fn.norm${1}.beta"),
];

/// Loads a reference PyTorch checkpoint (`torch.save` of a `dict[str, Tensor]` with the reference
/// key names; Linear weights are transposed, LayerNorm weight/bias become gamma/beta).
///
/// Fails on any shape mismatch, and on missing parameters unless `allow_missing`.
/// Unused tensors are reported, not fatal.
pub fn load_pytorch<B: Backend>(
    model: &mut CREStereo<B>,
    path: impl AsRef<Path>,
    allow_missing: bool,
) -> Result<ImportReport> {
    let path = path.as_ref();
    if !path.exists() {
        bail!("weights file {} does not exist", path.display());
    }
    // Burn's reader takes the file on trust (a deflated record may expand without end, a size
    // field or a shape may ask for terabytes, the pickle may name any class): it only sees files
    // that passed the state dict check.
    stereo_io::pth::check_state_dict(path)?;
    let mut store = PytorchStore::from_file(path)
        .map_indices_contiguous(false)
        .allow_partial(true)
        .validate(false);
    for (from, to) in KEY_REMAPS {
        store = store.with_key_remapping(*from, *to);
    }
    let result = model
        .load_from(&mut store)
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("reading PyTorch weights from {}", path.display()))?;
    if !result.errors.is_empty() {
        let msgs: Vec<String> = result.errors.iter().map(|e| format!("  {e:?}")).collect();
        bail!(
            "weights in {} do not fit the CREStereo model ({} errors, e.g. wrong shapes):\n{}",
            path.display(),
            msgs.len(),
            msgs.join("\n")
        );
    }
    let report = ImportReport {
        applied: result.applied.clone(),
        missing: result.missing.iter().map(|(p, _)| p.clone()).collect(),
        unused: result.unused.clone(),
    };
    if !allow_missing && !report.missing.is_empty() {
        bail!(
            "weights in {} lack parameters of the model:\n{report}",
            path.display()
        );
    }
    Ok(report)
}

/// Loads weights from a Burn record (`.mpk`, saved by [`save_record`]) or a PyTorch file
/// (`.pt` / `.pth`), chosen by extension. Returns the PyTorch import report when applicable.
pub fn load_weights<B: Backend>(
    model: CREStereo<B>,
    path: impl AsRef<Path>,
    device: &B::Device,
) -> Result<CREStereo<B>> {
    let path = path.as_ref();
    match path.extension().and_then(|e| e.to_str()) {
        Some("pt") | Some("pth") | Some("bin") => {
            if !path.is_file() {
                bail!(
                    "cannot read weights {}: the file does not exist",
                    path.display()
                );
            }
            let mut model = model;
            let report = load_pytorch(&mut model, path, false)?;
            eprint!("{}: {report}", path.display());
            Ok(model)
        }
        _ => load_record(model, path, device),
    }
}

fn recorder() -> NamedMpkBytesRecorder<FullPrecisionSettings> {
    NamedMpkBytesRecorder::<FullPrecisionSettings>::new()
}

/// The file of a record saved under `path`: `path` with the extension `.mpk` (the convention of
/// Burn's file recorder, kept so that records saved by earlier versions load).
pub fn record_file(path: impl AsRef<Path>) -> PathBuf {
    path.as_ref().with_extension("mpk")
}

/// Encodes any Burn record as named MessagePack (byte-identical to Burn's `NamedMpkFileRecorder`
/// files) and writes it through the project's durable-write path ([`stereo_io::write_bytes_atomically`]):
/// a full disk leaves no short record under the final name.
pub fn save_any_record<B: Backend, R: burn::record::Record<B>>(
    record: R,
    path: impl AsRef<Path>,
) -> Result<PathBuf> {
    let file = record_file(path);
    let bytes = Recorder::<B>::record(&recorder(), record, ())
        .map_err(|e| anyhow::anyhow!("encoding record {}: {e}", file.display()))?;
    stereo_io::write_bytes_atomically(&file, &bytes)?;
    Ok(file)
}

/// Reads a record written by [`save_any_record`]: `path` itself when it is a file, else
/// [`record_file`]`(path)`. A file that is not a record is named in the error.
pub fn load_any_record<B: Backend, R: burn::record::Record<B>>(
    path: impl AsRef<Path>,
    device: &B::Device,
) -> Result<R> {
    let file = record_path(path.as_ref());
    let (bytes, _) = read_record(&file)?;
    decode_record(bytes, &file, device)
}

/// `path` itself when it is a file, else [`record_file`]`(path)`.
fn record_path(path: &Path) -> PathBuf {
    if path.is_file() {
        path.to_path_buf()
    } else {
        record_file(path)
    }
}

fn decode_record<B: Backend, R: burn::record::Record<B>>(
    bytes: Vec<u8>,
    file: &Path,
    device: &B::Device,
) -> Result<R> {
    Recorder::<B>::load(&recorder(), bytes, device).map_err(|e| {
        anyhow::anyhow!(
            "{} is not a Burn record (.mpk) of this network, nor PyTorch weights (.pt/.pth): {e}",
            file.display()
        )
    })
}

/// The bytes of the record file at `file`, within the limits policy's one buffer, and its
/// tensors, each checked to hold exactly its shape's bytes ([`crate::weights::mpk`]): Burn would
/// end the process in an assertion on one that does not.
fn read_record(file: &Path) -> Result<(Vec<u8>, Vec<crate::weights::mpk::RecordTensor>)> {
    let limit = stereo_io::limits::MAX_ALLOC;
    let bytes = stereo_io::limits::read_file_capped(file, limit, "a Burn record")
        .with_context(|| format!("cannot read weights {}", file.display()))?;
    let tensors = crate::weights::mpk::record_tensors(&bytes, file)?;
    Ok((bytes, tensors))
}

/// Every parameter's shape by the path a record nests it under (`item.<module path>.param`),
/// from Burn's own listing of the module's tensors (no data is read).
fn record_parameter_shapes<B: Backend>(
    model: &CREStereo<B>,
) -> std::collections::BTreeMap<String, Vec<u64>> {
    model
        .collect(None, None, false)
        .into_iter()
        .map(|t| {
            let shape = t.shape.iter().map(|&d| d as u64).collect();
            (format!("item.{}.param", t.full_path()), shape)
        })
        .collect()
}

/// Saves the model as a Burn named-MessagePack record (full precision) at [`record_file`]`(path)`.
pub fn save_record<B: Backend>(model: &CREStereo<B>, path: impl AsRef<Path>) -> Result<PathBuf> {
    save_any_record::<B, _>(model.clone().into_record(), path)
}

/// Loads a Burn record saved by [`save_record`].
pub fn load_record<B: Backend>(
    model: CREStereo<B>,
    path: impl AsRef<Path>,
    device: &B::Device,
) -> Result<CREStereo<B>> {
    let file = record_path(path.as_ref());
    let (bytes, tensors) = read_record(&file)?;
    // Each tensor at a parameter of this network with its shape: Burn would load one of another
    // shape and fail later, inside the forward pass.
    crate::weights::mpk::check_against(&tensors, &record_parameter_shapes(&model), &file)?;
    Ok(model.load_record(decode_record(bytes, &file, device)?))
}

/// The reference (PyTorch) key of a Burn parameter path (inverse of the import remapping).
pub fn reference_key(burn_path: &str) -> String {
    let mut parts: Vec<String> = burn_path.split('.').map(str::to_string).collect();
    let mut out: Vec<String> = Vec::with_capacity(parts.len() + 2);
    let last = parts.len() - 1;
    let in_norm = parts.len() >= 2 && parts[parts.len() - 2].starts_with("norm");
    if in_norm {
        if parts[last] == "gamma" {
            parts[last] = "weight".into();
        } else if parts[last] == "beta" {
            parts[last] = "bias".into();
        }
    }
    for (i, p) in parts.iter().enumerate() {
        match p.as_str() {
            "self_att_fn" | "cross_att_fn" if i == 0 => {
                out.push(p.clone());
                out.push("layers".into());
                out.push("0".into());
            }
            "mlp1" => out.extend(["mlp".into(), "0".into()]),
            "mlp2" => out.extend(["mlp".into(), "2".into()]),
            "mask1" if i == 1 && parts[0] == "update_block" => {
                out.extend(["mask".into(), "0".into()])
            }
            "mask2" if i == 1 && parts[0] == "update_block" => {
                out.extend(["mask".into(), "2".into()])
            }
            "downsample" => out.extend(["downsample".into(), "0".into()]),
            _ => out.push(p.clone()),
        }
    }
    out.join(".")
}

/// A named float tensor in the reference layout (Linear weights as (out, in)); the PyTorch
/// state dict writer ([`stereo_io::pth::write_state_dict`]) takes these.
pub use stereo_io::pth::NamedArray;

fn tensor_to_reference_layout<B: Backend, const D: usize>(
    t: Tensor<B, D>,
) -> (Vec<usize>, Vec<f32>) {
    let t = if D == 2 { t.transpose() } else { t };
    let shape = t.dims().to_vec();
    let data = t
        .into_data()
        .convert::<f32>()
        .into_vec::<f32>()
        .expect("float tensor");
    (shape, data)
}

/// Every parameter of the model with its reference key, in the reference layout.
pub fn named_parameters<B: Backend>(model: &CREStereo<B>) -> Vec<NamedArray> {
    struct Values;
    impl<B: Backend> ParameterView<B> for Values {
        fn view<const D: usize>(&self, param: &Param<Tensor<B, D>>) -> (Vec<usize>, Vec<f32>) {
            tensor_to_reference_layout(param.val())
        }
    }
    collect_named(model, Values)
}

/// Gradients of every parameter (reference keys and layout); parameters without a gradient
/// are returned as zeros.
pub fn named_gradients<B: burn::tensor::backend::AutodiffBackend>(
    model: &CREStereo<B>,
    grads: &B::Gradients,
) -> Vec<NamedArray> {
    struct Gradients<'a, B: burn::tensor::backend::AutodiffBackend>(&'a B::Gradients);
    impl<B: burn::tensor::backend::AutodiffBackend> ParameterView<B> for Gradients<'_, B> {
        fn view<const D: usize>(&self, param: &Param<Tensor<B, D>>) -> (Vec<usize>, Vec<f32>) {
            let t = param.val();
            match t.grad(self.0) {
                Some(g) => tensor_to_reference_layout(g),
                None => {
                    let (shape, data) = tensor_to_reference_layout(t.inner());
                    (shape, vec![0.0; data.len()])
                }
            }
        }
    }
    collect_named(model, Gradients::<B>(grads))
}

/// What [`collect_named`] records of each parameter: its shape and values in the reference
/// layout.
trait ParameterView<B: Backend> {
    fn view<const D: usize>(&self, param: &Param<Tensor<B, D>>) -> (Vec<usize>, Vec<f32>);
}

/// Visits every parameter of `model` in module order, naming each by its reference key.
fn collect_named<B: Backend>(model: &CREStereo<B>, view: impl ParameterView<B>) -> Vec<NamedArray> {
    struct Named<V> {
        path: Vec<String>,
        view: V,
        out: Vec<NamedArray>,
    }
    impl<B: Backend, V: ParameterView<B>> burn::module::ModuleVisitor<B> for Named<V> {
        fn enter_module(&mut self, name: &str, _c: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _c: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<B, D>>) {
            let (shape, data) = self.view.view(param);
            self.out.push(NamedArray {
                name: reference_key(&self.path.join(".")),
                shape,
                data,
            });
        }
    }
    let mut v = Named {
        path: Vec::new(),
        view,
        out: Vec::new(),
    };
    model.visit(&mut v);
    v.out
}
