//! The model's graph against its `forward`, level by level: the three levels' inputs, each
//! level's refinement (the granularity where `emit`'s deliberate savings agree with `forward`:
//! the 1/16 cross-attention once instead of per iteration, the mask head at the last iteration
//! only) and the whole pass, with and without an initial flow.

use super::*;
use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
use crate::network::refine::{EmittedLevel, EmittedLookup, LevelInputs, Lookup};
use crate::test_util::uniform;
use crate::{CpuBackend, NoObserver};

type F = CpuBackend;

fn model() -> CREStereo<F> {
    CREStereoConfig::new().init_seeded::<F>(11, &Default::default())
}

/// Feature maps at 1/4 of a 64×96 pair (1/16: 4×6).
fn features() -> (Tensor<F, 4>, Tensor<F, 4>) {
    (
        uniform([1, 256, 16, 24], -2.0, 2.0),
        uniform([1, 256, 16, 24], -2.0, 2.0),
    )
}

/// A level's tensors in a fixed order (left, right, offsets where it has them, net, inp).
fn level_tensors(level: &LevelInputs<F>) -> Vec<Tensor<F, 4>> {
    let mut out = match &level.lookup {
        Lookup::AttendedOffsets { corr, offsets } | Lookup::Offsets { corr, offsets } => {
            vec![corr.fmap1.clone(), corr.fmap2.clone(), offsets.clone()]
        }
        Lookup::Warp { corr } => vec![corr.fmap1.clone(), corr.fmap2.clone()],
    };
    out.extend([level.net.clone(), level.inp.clone()]);
    out
}

fn emitted_values(level: EmittedLevel) -> Vec<Value> {
    let mut out = match level.lookup {
        EmittedLookup::AttendedOffsets {
            left,
            right,
            offsets,
        }
        | EmittedLookup::Offsets {
            left,
            right,
            offsets,
        } => vec![left, right, offsets],
        EmittedLookup::Warp { left, right } => vec![left, right],
    };
    out.extend([level.net, level.inp]);
    out
}

/// Pooling, offsets, hidden state and context split, position encoding and self-attention of
/// the 1/16 maps.
#[test]
fn emitted_levels_match_forward() {
    let model = model();
    let (fmap1, fmap2) = features();
    let out = run_emitted(&[fmap1.to_data(), fmap2.to_data()], |g, x| {
        let levels = model.emit_levels(g, x[0].clone(), x[1].clone());
        levels.into_iter().flat_map(emitted_values).collect()
    });
    let Levels {
        quarter,
        eighth,
        sixteenth,
    } = model.levels(fmap1, fmap2, &mut NoObserver);
    let forward: Vec<Tensor<F, 4>> = [quarter, eighth, sixteenth]
        .iter()
        .flat_map(level_tensors)
        .collect();
    assert_eq!(out.len(), forward.len());
    for (i, (emitted, forward)) in out.iter().zip(forward).enumerate() {
        assert_emit_matches(
            &format!("level value {i}"),
            emitted,
            forward.into_data(),
            1e-5,
        );
    }
}

/// Each level refined for two iterations (both search windows) from the same inputs and flow:
/// the last convex-upsampled flow, the one the next level takes over.
#[test]
fn emitted_refinement_matches_forward_level_by_level() {
    let model = model();
    let (fmap1, fmap2) = features();
    let Levels {
        quarter,
        eighth,
        sixteenth,
    } = model.levels(fmap1, fmap2, &mut NoObserver);
    for level in [sixteenth, eighth, quarter] {
        let kind = level.lookup.level();
        let [h, w] = level.size();
        let flow = uniform([1, 2, h, w], -3.0, 3.0);
        let tensors = level_tensors(&level);
        let mut inputs: Vec<TensorData> = tensors.iter().map(|t| t.to_data()).collect();
        inputs.push(flow.to_data());
        let out = run_emitted(&inputs, |g, x| {
            let (lookup, rest) = match kind {
                Level::Sixteenth => (
                    EmittedLookup::AttendedOffsets {
                        left: x[0].clone(),
                        right: x[1].clone(),
                        offsets: x[2].clone(),
                    },
                    3,
                ),
                Level::Eighth => (
                    EmittedLookup::Offsets {
                        left: x[0].clone(),
                        right: x[1].clone(),
                        offsets: x[2].clone(),
                    },
                    3,
                ),
                Level::Quarter => (
                    EmittedLookup::Warp {
                        left: x[0].clone(),
                        right: x[1].clone(),
                    },
                    2,
                ),
            };
            let level = EmittedLevel {
                lookup,
                net: x[rest].clone(),
                inp: x[rest + 1].clone(),
            };
            vec![
                model
                    .refiner()
                    .emit_refine_level(g, level, x[rest + 2].clone(), 2),
            ]
        });
        let mut predictions = Vec::new();
        let forward =
            model
                .refiner()
                .refine_level(level, flow, 2, &mut predictions, &mut NoObserver);
        let diff = assert_emit_matches(&format!("{kind:?}"), &out[0], forward.into_data(), 1e-4);
        println!("{kind:?}: max |emit − forward| = {diff:.2e}");
    }
}

/// The whole pass (normalisation, encoder, levels, cascade of levels), without and with an
/// initial flow: the last prediction.
#[test]
fn emitted_model_matches_forward() {
    let model = model();
    let (h, w) = (64, 96);
    let left = uniform([1, 3, h, w], 0.0, 255.0);
    let right = uniform([1, 3, h, w], 0.0, 255.0);
    let init = uniform([1, 2, h / 8, w / 8], -2.0, 2.0);
    let out = run_emitted(
        &[left.to_data(), right.to_data(), init.to_data()],
        |g, x| {
            vec![
                model.emit_forward(g, &x[0], &x[1], 2, None),
                model.emit_forward(g, &x[0], &x[1], 2, Some(&x[2])),
            ]
        },
    );
    for (i, init) in [None, Some(init)].into_iter().enumerate() {
        let label = if init.is_some() {
            "with flow_init"
        } else {
            "from zero"
        };
        let forward = model
            .forward(left.clone(), right.clone(), 2, init)
            .pop()
            .expect("a prediction");
        let diff = assert_emit_matches(label, &out[i], forward.into_data(), 1e-4);
        println!("whole pass, {label}: max |emit − forward| = {diff:.2e}");
    }
}
