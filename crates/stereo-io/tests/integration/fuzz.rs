//! Random and mutated bytes through the EXR, PFM, 16-bit PNG disparity and .npy readers: each must
//! return (Ok or an error naming the file), never panic. `STEREO_IO_FUZZ_CASES` raises the case
//! count for a long run (the suite keeps a short one).

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use stereo_io::*;

use crate::io_fixtures::left_view_meta;

fn cases() -> u32 {
    std::env::var("STEREO_IO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(300)
}

fn valid_files() -> (Vec<u8>, Vec<u8>, Vec<u8>, Vec<u8>) {
    let dir = tempfile::tempdir().unwrap();
    let mut m = DisparityMap::new(13, 7);
    for (i, (d, v)) in m.data.iter_mut().zip(m.valid.iter_mut()).enumerate() {
        *v = i % 5 != 0;
        *d = if *v { i as f32 * 0.75 } else { 0.0 };
    }
    let meta = left_view_meta(100.0, 0.1);
    let (e, p, n) = (
        dir.path().join("a.exr"),
        dir.path().join("a.pfm"),
        dir.path().join("a.png"),
    );
    write_disparity_exr(&e, &m, &meta).unwrap();
    write_disparity_pfm(&p, &m).unwrap();
    write_disparity_png16(&n, &m, 32.0).unwrap();
    let y = dir.path().join("a.npy");
    write_disparity_npy(&y, &m).unwrap();
    (
        std::fs::read(e).unwrap(),
        std::fs::read(p).unwrap(),
        std::fs::read(n).unwrap(),
        std::fs::read(y).unwrap(),
    )
}

/// Applies a mutation: overwrite bytes, truncate, or insert.
fn mutate(
    base: &[u8],
    edits: &[(usize, u8)],
    cut: Option<usize>,
    insert: Option<(usize, Vec<u8>)>,
) -> Vec<u8> {
    let mut b = base.to_vec();
    for &(at, v) in edits {
        if !b.is_empty() {
            let i = at % b.len();
            b[i] = v;
        }
    }
    if let Some((at, bytes)) = insert {
        let i = at % (b.len() + 1);
        b.splice(i..i, bytes);
    }
    if let Some(c) = cut {
        b.truncate(c % (b.len() + 1));
    }
    b
}

static OK: AtomicUsize = AtomicUsize::new(0);
static ERR: AtomicUsize = AtomicUsize::new(0);

fn check(
    name: &str,
    r: std::result::Result<impl Sized, Error>,
) -> std::result::Result<(), TestCaseError> {
    if r.is_ok() {
        OK.fetch_add(1, Ordering::Relaxed);
    }
    if let Err(e) = r {
        ERR.fetch_add(1, Ordering::Relaxed);
        let msg = e.to_string();
        prop_assert!(msg.contains(name), "error does not name the file: {msg}");
    }
    Ok(())
}

fn run_all(bytes: &[u8]) -> std::result::Result<(), TestCaseError> {
    check("f.exr", decode_disparity_exr(bytes, Path::new("f.exr")))?;
    check("f.pfm", decode_pfm(bytes, Path::new("f.pfm")))?;
    check(
        "f.png",
        decode_disparity_png16(bytes, Path::new("f.png"), 32.0),
    )?;
    check(
        "f.npy",
        stereo_io::npy::decode_npy(bytes, Path::new("f.npy")),
    )?;
    Ok(())
}

/// Runs [`cases`] cases of `strategy` through `test` (no failures persisted), then reports the
/// decoders' results so far, labelled `what`.
fn run_cases<S: Strategy>(
    what: &str,
    strategy: &S,
    test: impl Fn(S::Value) -> std::result::Result<(), TestCaseError>,
) {
    let mut runner = TestRunner::new(Config {
        cases: cases(),
        failure_persistence: None,
        ..Config::default()
    });
    runner.run(strategy, test).unwrap();
    eprintln!(
        "{what}: {} cases; decoder results so far: {} ok, {} errors",
        cases(),
        OK.load(Ordering::Relaxed),
        ERR.load(Ordering::Relaxed)
    );
}

#[test]
fn readers_never_panic_on_mutated_files() {
    let (exr, pfm, png, npy) = valid_files();
    // The unmutated files decode.
    decode_disparity_exr(&exr, Path::new("a.exr")).unwrap();
    decode_pfm(&pfm, Path::new("a.pfm")).unwrap();
    decode_disparity_png16(&png, Path::new("a.png"), 32.0).unwrap();
    stereo_io::npy::decode_npy(&npy, Path::new("a.npy")).unwrap();
    let strategy = (
        0usize..4,
        prop::collection::vec((any::<usize>(), any::<u8>()), 0..8),
        prop::option::of(any::<usize>()),
        prop::option::of((any::<usize>(), prop::collection::vec(any::<u8>(), 1..16))),
    );
    run_cases("mutated", &strategy, |(which, edits, cut, insert)| {
        let base = [&exr, &pfm, &png, &npy][which];
        run_all(&mutate(base, &edits, cut, insert))
    });
}

#[test]
fn readers_never_panic_on_random_bytes() {
    // Random tails after each format's magic, so the parsers get past the first check.
    let strategy = (0usize..5, prop::collection::vec(any::<u8>(), 0..512));
    run_cases("random", &strategy, |(prefix, tail)| {
        let magic: &[u8] = [
            &b""[..],
            b"\x76\x2f\x31\x01",
            b"Pf\n",
            b"\x89PNG\r\n\x1a\n",
            b"\x93NUMPY\x01\x00",
        ][prefix];
        let mut bytes = magic.to_vec();
        bytes.extend_from_slice(&tail);
        run_all(&bytes)
    });
}
