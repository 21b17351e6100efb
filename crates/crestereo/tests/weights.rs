//! Weight import errors and Burn record round trip.

mod common;

use burn::prelude::*;
use common::*;
use crestereo::weights::{load_pytorch, load_record, save_record};
use crestereo::{CREStereoConfig, CpuBackend};

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
