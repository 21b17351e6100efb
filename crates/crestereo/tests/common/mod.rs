//! Shared helpers for the parity tests.
#![allow(dead_code)]

use std::path::PathBuf;

use burn::prelude::*;
use crestereo::npy::{Array, read_npy};
use crestereo::weights::load_pytorch;
use crestereo::{CREStereo, CREStereoConfig};

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
    read_npy(fixtures().join(rel)).unwrap()
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
