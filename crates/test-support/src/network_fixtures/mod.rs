//! Shared helpers for the parity tests.

pub mod network_checks;

use std::path::PathBuf;

use burn::prelude::*;
use crestereo::weights::load_pytorch;
use crestereo::{CREStereo, CREStereoConfig, ForwardObserver, IterationOutputs, Level};
use stereo_io::{NpyArray as Array, read_npy};

/// `shared/reference/crestereo` beside the repository clone (override: `CRESTEREO_FIXTURES`).
pub fn fixtures() -> PathBuf {
    let dir = std::env::var_os("CRESTEREO_FIXTURES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/reference/crestereo")
        });
    assert!(
        dir.join("weights_seed0.pt").exists(),
        "CREStereo fixtures not found at {} (expected shared/ beside the repository, or set CRESTEREO_FIXTURES)",
        dir.display()
    );
    dir
}

pub fn npy(rel: &str) -> Array {
    read_npy(&fixtures().join(rel)).unwrap()
}

pub fn tensor<B: Backend, const D: usize>(a: &Array, device: &B::Device) -> Tensor<B, D> {
    let shape: [usize; D] = a
        .shape
        .clone()
        .try_into()
        .unwrap_or_else(|_| panic!("rank mismatch: {:?}", a.shape));
    Tensor::from_data(TensorData::new(a.data.clone(), shape), device)
}

pub fn values<B: Backend, const D: usize>(t: Tensor<B, D>) -> Vec<f32> {
    t.into_data().convert::<f32>().into_vec::<f32>().unwrap()
}

pub fn model<B: Backend>(device: &B::Device) -> CREStereo<B> {
    let mut m = CREStereoConfig::new().init::<B>(device);
    let report = load_pytorch(&mut m, fixtures().join("weights_seed0.pt"), false).unwrap();
    assert!(
        report.missing.is_empty() && report.unused.is_empty(),
        "{report}"
    );
    m
}

/// Max absolute error and max |reference|.
pub fn max_err(ours: &[f32], reference: &[f32]) -> (f32, f32) {
    assert_eq!(ours.len(), reference.len(), "length mismatch");
    let mut e = 0f32;
    let mut m = 0f32;
    for (a, b) in ours.iter().zip(reference) {
        assert!(a.is_finite(), "non-finite output");
        e = e.max((a - b).abs());
        m = m.max(b.abs());
    }
    (e, m)
}

/// Checks `ours` against `reference` with tolerance `tol · max(1, max|reference|)`; returns the
/// scaled error.
pub fn check(name: &str, ours: &[f32], reference: &[f32], tol: f32) -> f32 {
    let (e, m) = max_err(ours, reference);
    let scaled = e / m.max(1.0);
    println!("{name:<40} max|err| {e:.3e}  (max|ref| {m:.3e}, scaled {scaled:.3e})");
    assert!(
        scaled <= tol,
        "{name}: max error {e:.3e} exceeds {tol:e} (max|ref| {m:.3e})"
    );
    scaled
}

/// Width, height and values of a disparity EXR (the CLI's output).
pub fn read_exr(path: &std::path::Path) -> stereo_io::Result<(usize, usize, Vec<f32>)> {
    let (map, _) = stereo_io::read_disparity_exr(path)?;
    Ok((map.width, map.height, map.data))
}

/// The intermediates of one forward pass that the parity tests compare with the fixtures,
/// collected through the model's observer hook.
pub struct Recorder<B: Backend> {
    pub fmap1: Option<Tensor<B, 4>>,
    pub fmap2: Option<Tensor<B, 4>>,
    /// Positional encoding table (d_model, H/16, W/16).
    pub pos_encoding: Option<Tensor<B, 3>>,
    pub selfatt_left_tokens: Option<Tensor<B, 3>>,
    pub selfatt_right_tokens: Option<Tensor<B, 3>>,
    /// Output tokens of the first cross-attention call (1/16, iteration 0).
    pub crossatt_left_tokens_call0: Option<Tensor<B, 3>>,
    pub crossatt_right_tokens_call0: Option<Tensor<B, 3>>,
    pub conv_offset_16_raw: Option<Tensor<B, 4>>,
    pub conv_offset_8_raw: Option<Tensor<B, 4>>,
    /// Every correlation call, in order.
    pub corr: Vec<Tensor<B, 4>>,
    /// Every update-block call: Δflow, up-mask and new hidden state.
    pub delta_flow: Vec<Tensor<B, 4>>,
    pub up_mask: Vec<Tensor<B, 4>>,
    pub net: Vec<Tensor<B, 4>>,
}

impl<B: Backend> Default for Recorder<B> {
    fn default() -> Self {
        Self {
            fmap1: None,
            fmap2: None,
            pos_encoding: None,
            selfatt_left_tokens: None,
            selfatt_right_tokens: None,
            crossatt_left_tokens_call0: None,
            crossatt_right_tokens_call0: None,
            conv_offset_16_raw: None,
            conv_offset_8_raw: None,
            corr: Vec::new(),
            delta_flow: Vec::new(),
            up_mask: Vec::new(),
            net: Vec::new(),
        }
    }
}

impl<B: Backend> ForwardObserver<B> for Recorder<B> {
    fn features(&mut self, left: &Tensor<B, 4>, right: &Tensor<B, 4>) {
        self.fmap1 = Some(left.clone());
        self.fmap2 = Some(right.clone());
    }

    fn offset_logits(&mut self, level: Level, logits: &Tensor<B, 4>) {
        match level {
            Level::Sixteenth => self.conv_offset_16_raw = Some(logits.clone()),
            Level::Eighth => self.conv_offset_8_raw = Some(logits.clone()),
            Level::Quarter => panic!("the 1/4 level has no learned offsets"),
        }
    }

    fn positional_encoding(&mut self, table: &Tensor<B, 3>) {
        self.pos_encoding = Some(table.clone());
    }

    fn self_attention(&mut self, left: &Tensor<B, 3>, right: &Tensor<B, 3>) {
        self.selfatt_left_tokens = Some(left.clone());
        self.selfatt_right_tokens = Some(right.clone());
    }

    fn cross_attention(&mut self, iteration: usize, left: &Tensor<B, 3>, right: &Tensor<B, 3>) {
        if iteration == 0 {
            self.crossatt_left_tokens_call0 = Some(left.clone());
            self.crossatt_right_tokens_call0 = Some(right.clone());
        }
    }

    fn iteration(&mut self, step: &IterationOutputs<'_, B>) {
        self.corr.push(step.corr.clone());
        self.delta_flow.push(step.delta_flow.clone());
        self.up_mask.push(step.up_mask.clone());
        self.net.push(step.net.clone());
    }
}
