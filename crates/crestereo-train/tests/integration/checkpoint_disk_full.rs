//! Checkpoints on a filesystem that fills up (a small tmpfs of the test's own, shared with
//! stereo-io's disk-full tests): a save that runs out of space fails naming the file and the OS
//! error once, leaves neither a partial checkpoint nor its temp directory, and the previous
//! checkpoint stays whole and loadable.

use std::path::Path;

use test_support::small_fs_or_skip;

use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use crestereo::{CREStereo, CREStereoConfig, CpuAutodiffBackend};
use crestereo_train::checkpoint::{TrainState, list_checkpoints, load_checkpoint, save_checkpoint};

type B = CpuAutodiffBackend;

fn state(step: u64) -> TrainState {
    TrainState {
        step,
        samples: step * 2,
        seed: 7,
        skipped_steps: 0,
        elapsed_s: 1.5,
    }
}

fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn a_full_disk_never_leaves_a_partial_checkpoint() {
    let fs = small_fs_or_skip!(160 << 20);
    let device = Default::default();
    let mut model: CREStereo<B> = CREStereoConfig::new().init(&device);
    let mut optim = AdamConfig::new().init::<B, CREStereo<B>>();
    // One real step, so the optimiser holds its moments (most of a checkpoint's bytes).
    let left = Tensor::<B, 4>::random(
        [1, 3, 32, 64],
        burn::tensor::Distribution::Uniform(0.0, 255.0),
        &device,
    );
    let right = left.clone();
    let out = model.forward(left, right, 1, None).pop().unwrap();
    let grads = GradientsParams::from_grads(out.abs().mean().backward(), &model);
    model = optim.step(1e-4, model, grads);

    let run = fs.path().join("run");
    let first = save_checkpoint(&run, &model, &optim, &state(1), 3).expect("room for one");
    let used: u64 = std::fs::read_dir(&first)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    println!("one checkpoint: {used} bytes");

    // Too little room for a second one, at several fill levels: during the model, during the
    // optimiser state, and with only a page left.
    for leave in [4096, used / 4, used * 3 / 4] {
        let filler = fs.fill_leaving(leave);
        let err = save_checkpoint(&run, &model, &optim, &state(2), 3)
            .expect_err("a checkpoint cannot fit");
        let msg = format!("{err:#}");
        assert!(msg.contains("step-00000002"), "{msg}");
        assert_eq!(msg.matches("os error 28").count(), 1, "{msg}");
        assert_eq!(
            entries(&run.join("checkpoints")),
            ["step-00000001"],
            "{leave} bytes free: something partial was left"
        );
        std::fs::remove_file(filler).unwrap();
    }
    // The survivor is whole: it lists and loads, state and all.
    assert_eq!(list_checkpoints(&run).unwrap().len(), 1);
    let fresh: CREStereo<B> = CREStereoConfig::new().init(&device);
    let back = load_checkpoint(
        &first,
        fresh,
        AdamConfig::new().init::<B, CREStereo<B>>(),
        &device,
    )
    .unwrap();
    assert_eq!(back.state, state(1));
    let w = |m: &CREStereo<B>| crestereo::weights::named_parameters(m);
    assert_eq!(
        w(&back.model).iter().map(|p| &p.data).collect::<Vec<_>>(),
        w(&model).iter().map(|p| &p.data).collect::<Vec<_>>()
    );
    // With room again, the save succeeds.
    save_checkpoint(&run, &model, &optim, &state(2), 3).unwrap();
    assert_eq!(
        entries(&run.join("checkpoints")),
        ["step-00000001", "step-00000002"]
    );
}
