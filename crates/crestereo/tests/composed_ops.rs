//! The network with every hand-written kernel switched off (`dispatch::use_composed_ops`):
//! what a backend without kernels runs. The composed ops must meet the same bounds as the
//! kernels: the AGCL checks (the dispatched op is then the composed one), the reference
//! fixtures' forward and two-pass inference, and the gradient directions. Every test switches
//! the kernels off first; the switch is process-wide, and this file is its own process.

use crestereo::ops::dispatch::{Kernels, kernels, use_composed_ops};
use crestereo::{CpuAutodiffBackend, CpuBackend};
use test_support::agcl_checks;
use test_support::network_fixtures::network_checks;

type B = CpuBackend;
type A = CpuAutodiffBackend;

fn composed() {
    use_composed_ops(true);
    assert_eq!(kernels::<B>(&Default::default()), Kernels::Composed);
    assert_eq!(kernels::<A>(&Default::default()), Kernels::Composed);
}

#[test]
fn agcl_composed_matches_reference() {
    composed();
    agcl_checks::offset_corr_forward::<B>();
    agcl_checks::warp_forward::<B>();
    agcl_checks::shift_corr_forward_and_gradients::<B, A>();
    agcl_checks::offset_corr_and_warp_gradients::<A>();
}

#[test]
fn composed_train_forward_matches_fixtures() {
    composed();
    network_checks::train_forward_intermediates_predictions_and_loss::<B>(&Default::default());
}

#[test]
fn composed_two_pass_inference_matches_fixtures() {
    composed();
    network_checks::eval_two_pass_cascade::<B>(&Default::default());
}

#[test]
fn composed_gradients_agree_in_direction() {
    composed();
    let w = network_checks::gradients::<A>(&Default::default(), false);
    network_checks::assert_float32_gradients(&w);
}
