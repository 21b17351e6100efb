//! Shared helpers of the `crestereo` command tests: the reference fixtures.
#![allow(dead_code)]

use std::path::PathBuf;

use crestereo::npy::{Array, read_npy};

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
