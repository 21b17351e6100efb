//! The network with every hand-written kernel switched off (`dispatch::use_composed_ops`):
//! what a backend without kernels runs. The composed ops must meet the same bounds as the
//! kernels: the AGCL checks (the dispatched op is then the composed one), the reference
//! fixtures' forward and two-pass inference, and the gradient directions.
//!
//! The switch is process-wide and the other modules' tests run beside these in this binary, so
//! each test here runs its checks in a child process of this test binary (`--exact`, that one
//! test), which switches the kernels off first.

use std::process::Command;

use crestereo::ops::dispatch::{Kernels, kernels, use_composed_ops};
use crestereo::{CpuAutodiffBackend, CpuBackend};
use test_support::agcl_checks;
use test_support::network_fixtures::network_checks;

type B = CpuBackend;
type A = CpuAutodiffBackend;

/// Set in the child process that runs one test's checks.
const CHILD: &str = "CRESTEREO_TEST_COMPOSED_CHILD";

/// Runs `checks` with every kernel switched off: here when this is the child, else in a child
/// process that runs this module's test `test` alone; its failure is this test's.
fn composed(test: &str, checks: impl FnOnce()) {
    if std::env::var_os(CHILD).is_some() {
        use_composed_ops(true);
        assert_eq!(kernels::<B>(&Default::default()), Kernels::Composed);
        assert_eq!(kernels::<A>(&Default::default()), Kernels::Composed);
        checks();
        return;
    }
    let name = format!("composed_ops::{test}");
    let exe = std::env::current_exe().expect("this test binary");
    let out = Command::new(exe)
        .args([
            name.as_str(),
            "--exact",
            "--test-threads",
            "1",
            "--nocapture",
        ])
        .env(CHILD, "1")
        .output()
        .expect("run this test binary again");
    let said = test_support::output_text(&out);
    assert!(out.status.success(), "{name}, kernels off:\n{said}");
    assert!(
        said.contains("test result: ok. 1 passed"),
        "the child ran {name}:\n{said}"
    );
    print!("{said}");
}

#[test]
fn agcl_composed_matches_reference() {
    composed("agcl_composed_matches_reference", || {
        agcl_checks::offset_corr_forward::<B>();
        agcl_checks::warp_forward::<B>();
        agcl_checks::shift_corr_forward_and_gradients::<B, A>();
        agcl_checks::offset_corr_and_warp_gradients::<A>();
    });
}

#[test]
fn composed_train_forward_matches_fixtures() {
    composed("composed_train_forward_matches_fixtures", || {
        network_checks::train_forward_intermediates_predictions_and_loss::<B>(&Default::default());
    });
}

#[test]
fn composed_two_pass_inference_matches_fixtures() {
    composed("composed_two_pass_inference_matches_fixtures", || {
        network_checks::eval_two_pass_cascade::<B>(&Default::default());
    });
}

#[test]
fn composed_gradients_agree_in_direction() {
    composed("composed_gradients_agree_in_direction", || {
        let w = network_checks::gradients::<A>(&Default::default(), false);
        network_checks::assert_float32_gradients(&w);
    });
}
