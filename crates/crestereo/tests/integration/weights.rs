//! Weight import errors and Burn record round trip.

use crate::network_fixtures;
use burn::prelude::*;
use crestereo::weights::{load_pytorch, load_record, save_record};
use crestereo::{CREStereoConfig, CpuBackend};
use network_fixtures::*;

type B = CpuBackend;

#[test]
fn wrong_shapes_fail_clearly() {
    let device = Default::default();
    // 2 correlation groups → the motion encoder expects 18 correlation channels, not 36
    let mut m = CREStereoConfig::new().with_groups(2).init::<B>(&device);
    let err = load_pytorch(&mut m, fixtures().join("weights_seed0.pt"), false).unwrap_err();
    let msg = format!("{err:#}");
    println!("{msg}");
    assert!(
        msg.contains("update_block.encoder.convc1.weight") && msg.contains("ShapeMismatch"),
        "{msg}"
    );
}

#[test]
fn record_round_trip() {
    let device = Default::default();
    let m = model::<B>(&device);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crestereo");
    save_record(&m, &path).unwrap();
    let fresh = CREStereoConfig::new().init::<B>(&device);
    let loaded = load_record(fresh, &path, &device).unwrap();
    let a = crestereo::weights::named_parameters(&m);
    let b = crestereo::weights::named_parameters(&loaded);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.data, y.data, "{}", x.name);
    }
    // and a short forward agrees bit for bit
    let left = Tensor::<B, 4>::ones([1, 3, 32, 32], &device).mul_scalar(100.0);
    let right = Tensor::<B, 4>::ones([1, 3, 32, 32], &device).mul_scalar(90.0);
    let p1 = values(
        m.forward(left.clone(), right.clone(), 2, None)
            .pop()
            .unwrap(),
    );
    let p2 = values(loaded.forward(left, right, 2, None).pop().unwrap());
    assert_eq!(p1, p2);
}

/// Records are encoded in memory and written through the durable-write path, in Burn's named
/// MessagePack format: a record saved by Burn's own file recorder (every checkpoint of earlier
/// versions) loads through ours, and ours through Burn's. (The bytes differ only in the
/// recorder's type name in the metadata, which loading does not check.)
#[test]
fn records_interchange_with_burns_file_recorder() {
    use burn::record::{FullPrecisionSettings, NamedMpkFileRecorder};
    let device = Default::default();
    let m = model::<B>(&device);
    let dir = tempfile::tempdir().unwrap();
    let ours = save_record(&m, dir.path().join("ours")).unwrap();
    assert_eq!(ours, dir.path().join("ours.mpk"));
    let recorder = NamedMpkFileRecorder::<FullPrecisionSettings>::new();
    m.clone()
        .save_file(dir.path().join("burns"), &recorder)
        .unwrap();
    let same = |other: &crestereo::CREStereo<B>| {
        let a = crestereo::weights::named_parameters(&m);
        let b = crestereo::weights::named_parameters(other);
        a.len() == b.len()
            && a.iter()
                .zip(&b)
                .all(|(x, y)| x.name == y.name && x.data == y.data)
    };
    let fresh = || CREStereoConfig::new().init::<B>(&device);
    assert!(same(
        &load_record(fresh(), dir.path().join("burns.mpk"), &device).unwrap()
    ));
    assert!(same(
        &fresh()
            .load_file(dir.path().join("ours"), &recorder, &device)
            .unwrap()
    ));
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "temp files left: {names:?}");
}

/// A file that is not weights is named as such (not "file not found"), and a missing one too.
#[test]
fn a_file_that_is_not_weights_is_named() {
    let device = Default::default();
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "these are not weights").unwrap();
    let fresh = || CREStereoConfig::new().init::<B>(&device);
    let msg = format!(
        "{:#}",
        crestereo::weights::load_weights(fresh(), &text, &device).unwrap_err()
    );
    assert!(
        msg.contains("notes.txt") && msg.contains("is not a Burn record"),
        "{msg}"
    );
    let missing = dir.path().join("missing.pt");
    let msg = format!(
        "{:#}",
        crestereo::weights::load_weights(fresh(), &missing, &device).unwrap_err()
    );
    assert!(
        msg.contains("missing.pt") && msg.contains("does not exist"),
        "{msg}"
    );
    let msg = format!(
        "{:#}",
        load_record(fresh(), dir.path().join("absent.mpk"), &device).unwrap_err()
    );
    assert!(
        msg.contains("absent.mpk") && msg.contains("cannot read"),
        "{msg}"
    );
}

/// A seeded network's weights depend on its seed only, while another thread builds and reads
/// networks of its own at the same time (all of Burn's initial draws come from one process-wide
/// RNG; a training loading a checkpoint beside another one starting from its seed once changed
/// the latter's first loss).
#[test]
fn seeded_weights_do_not_depend_on_other_threads() {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let device = Default::default();
    let bits = |m: &crestereo::CREStereo<B>| -> Vec<u32> {
        crestereo::weights::named_parameters(m)
            .iter()
            .flat_map(|p| p.data.iter().map(|v| v.to_bits()))
            .collect()
    };
    let alone = bits(&CREStereoConfig::new().init_seeded::<B>(7, &device));
    let (stop, built) = (AtomicBool::new(false), AtomicUsize::new(0));
    std::thread::scope(|scope| {
        let other = scope.spawn(|| {
            while !stop.load(Ordering::Relaxed) {
                let other = CREStereoConfig::new().init::<B>(&device);
                std::hint::black_box(crestereo::weights::named_parameters(&other));
                built.fetch_add(1, Ordering::Relaxed);
            }
        });
        while built.load(Ordering::Relaxed) == 0 && !other.is_finished() {
            std::thread::yield_now();
        }
        for round in 0..4 {
            let beside = bits(&CREStereoConfig::new().init_seeded::<B>(7, &device));
            assert!(beside == alone, "round {round}: the seeded weights changed");
        }
        stop.store(true, Ordering::Relaxed);
    });
}
