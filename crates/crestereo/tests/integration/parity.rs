//! Parity of the Burn port with the reference fixtures (Flex backend, CPU).

use crate::network_fixtures;
use burn::prelude::*;
use crestereo::weights::{REFERENCE_PARAM_COUNT, load_pytorch, named_parameters};
use crestereo::{CREStereoConfig, CpuBackend};
use network_fixtures::network_checks;
use network_fixtures::*;

type B = CpuBackend;

#[test]
fn parameter_count_and_import_report() {
    let device = Default::default();
    let mut m = CREStereoConfig::new().init::<B>(&device);
    assert_eq!(m.num_params(), REFERENCE_PARAM_COUNT);
    let report = load_pytorch(&mut m, fixtures().join("weights_seed0.pt"), false).unwrap();
    println!("{report}");
    assert_eq!(report.applied.len(), 94);
    assert!(report.missing.is_empty());
    assert!(report.unused.is_empty());
    // every reference tensor round-trips by name, shape and value
    let reference = std::fs::read_to_string(fixtures().join("state_dict_keys.txt")).unwrap();
    let params = named_parameters(&m);
    assert_eq!(params.len(), 94);
    for line in reference.lines().filter(|l| !l.trim().is_empty()) {
        let key = line.split('\t').next().unwrap();
        let p = params
            .iter()
            .find(|p| p.name == key)
            .unwrap_or_else(|| panic!("no parameter named {key}"));
        let expected: Vec<usize> = line
            .split('\t')
            .nth(1)
            .unwrap()
            .trim_matches(|c| c == '(' || c == ')')
            .split(',')
            .filter(|s| !s.trim().is_empty())
            .map(|s| s.trim().parse().unwrap())
            .collect();
        assert_eq!(p.shape, expected, "{key}");
    }
}

#[test]
fn train_forward_intermediates_predictions_and_loss() {
    network_checks::train_forward_intermediates_predictions_and_loss::<B>(&Default::default());
}
#[test]
fn eval_two_pass_cascade() {
    network_checks::eval_two_pass_cascade::<B>(&Default::default());
}
