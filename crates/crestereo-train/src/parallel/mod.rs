//! Data-parallel training: one replica of the network per device, several devices per process,
//! several processes (nodes) per run, gradients averaged by an all-reduce before every Adam step
//! so that the replicas stay identical.
//!
//! - [`topology`]: who this process is (flags, torchrun's or Slurm's environment).
//! - [`collective`]: the only calls into Burn's collective, with a timeout on each.
//! - [`liveness`]: a TCP connection per process to rank 0, so a dead process stops the others.
//! - [`flat`]: gradients and weights as one flat tensor in the model's parameter order.
//! - [`replica`]: what replicas exchange each step, at start and at checks.
//! - [`slurm`]: the `sbatch` script of a multi-node run.
//! - [`compare`]: how far apart two runs are (a parallel run against a one-device run).
//!
//! The global batch (`batch_size`) is split evenly: with R replicas each takes `batch_size / R`
//! samples per pass, the samples a one-replica run would take at that step
//! ([`crate::data::share`]). The loss of each replica is a mean over its pixels, so the mean of
//! the replicas' gradients is the gradient of the global batch's loss: an R-replica run follows a
//! one-replica run with the whole batch, to the rounding of the sums.

pub mod collective;
pub mod compare;
pub mod flat;
pub mod liveness;
pub mod replica;
pub mod slurm;
pub mod topology;

use std::path::Path;
use std::sync::mpsc;
use std::time::Duration;

use anyhow::{Context, Result, anyhow};
use burn::tensor::backend::AutodiffBackend;

use crate::config::TrainConfig;
use crate::train::{
    TrainOptions, TrainOutcome, check_batch_split, train_replica, with_chosen_splits,
};
use collective::{Collective, CollectiveSetup, Timeouts};
use liveness::{Hello, Liveness};
use replica::Replica;
use topology::ProcessGroup;

/// How a data-parallel run is laid out and how long its parts may wait for each other.
#[derive(Debug, Clone)]
pub struct ParallelOptions {
    /// Other processes of the run, if any.
    pub group: Option<ProcessGroup>,
    pub timeouts: Timeouts,
}

/// Trains a run with one replica per device of `devices` in this process (and the replicas of
/// the other processes of `options.group`). Returns replica 0's outcome (on every process: the
/// steps and losses are the run's).
pub fn train_parallel<B: AutodiffBackend>(
    cfg: &TrainConfig,
    run: &Path,
    opts: &TrainOptions,
    devices: &[B::Device],
    options: &ParallelOptions,
) -> Result<TrainOutcome> {
    cfg.validate()?;
    let (rank, processes) = options.group.as_ref().map_or((0, 1), |g| (g.rank, g.size));
    let local = devices.len();
    if local == 0 {
        return Err(anyhow!("no devices to train on"));
    }
    let replicas = processes * local;
    check_batch_split(cfg, replicas)?;
    // Splits resolved once, so the identity check below compares what is trained on.
    let cfg = &with_chosen_splits(cfg)?;
    if rank == 0 {
        tracing::info!(
            "data-parallel: {replicas} replicas ({processes} process{} × {local} device{}), {} samples per replica per pass",
            if processes == 1 { "" } else { "es" },
            if local == 1 { "" } else { "s" },
            cfg.batch_size / replicas
        );
    }
    let liveness = match &options.group {
        Some(g) => Some(join_group(cfg, run, opts, g, local, options.timeouts)?),
        None => None,
    };
    let setup = CollectiveSetup::new(local, options.group.as_ref())?;
    let replica = |d: usize, device: &B::Device| -> Result<TrainOutcome> {
        let index = rank * local + d;
        let collective =
            Collective::<B::InnerBackend>::join(index, device, &setup, options.timeouts)?;
        let replica = Replica {
            index,
            count: replicas,
            collective,
        };
        crate::oom::on_device(
            || train_replica::<B>(cfg, run, opts, device, replica),
            &format!("training (replica {index})"),
            crate::oom::TRAINING_ADVICE,
        )
    };
    let outcome = if local == 1 {
        // One device: the replica runs on this thread (on the CPU pool, where the command runs).
        replica(0, &devices[0])?
    } else {
        // Several: a plain thread each (a replica blocked in its all-reduce must not hold one of
        // the pool's threads), owned rather than scoped: when one fails the others may be
        // blocked in an all-reduce that never completes, and the error must not wait for them.
        let (tx, rx) = mpsc::channel::<(usize, Result<TrainOutcome>)>();
        for (d, device) in devices.iter().enumerate() {
            let index = rank * local + d;
            let (tx, setup, device) = (tx.clone(), setup.clone(), device.clone());
            let (cfg, run, opts) = (cfg.clone(), run.to_path_buf(), opts.clone());
            let timeouts = options.timeouts;
            std::thread::Builder::new()
                .name(format!("replica-{index}"))
                .spawn(move || {
                    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        let collective =
                            Collective::<B::InnerBackend>::join(index, &device, &setup, timeouts)?;
                        let replica = Replica {
                            index,
                            count: replicas,
                            collective,
                        };
                        crate::oom::on_device(
                            || train_replica::<B>(&cfg, &run, &opts, &device, replica),
                            &format!("training (replica {index})"),
                            crate::oom::TRAINING_ADVICE,
                        )
                    }))
                    .unwrap_or_else(|_| {
                        Err(anyhow!("replica {index} stopped: a panic (see above)"))
                    });
                    let _ = tx.send((index, result));
                })
                .context("cannot start a replica thread")?;
        }
        drop(tx);
        collect(rx, local, rank * local)?
    };
    if let Some(l) = liveness {
        l.finish(options.timeouts.join)?;
    }
    Ok(outcome)
}

/// Replica `first`'s outcome once all `local` replicas of this process succeeded; the first
/// error otherwise (without waiting for the others, which may be blocked for ever).
fn collect(
    rx: mpsc::Receiver<(usize, Result<TrainOutcome>)>,
    local: usize,
    first: usize,
) -> Result<TrainOutcome> {
    let mut lead = None;
    for _ in 0..local {
        let (index, result) = collective::wait_on_pool(|| match rx.try_recv() {
            Ok(r) => Some(Some(r)),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(None),
        })
        .ok_or_else(|| anyhow!("a replica thread ended without a result"))?;
        let outcome = result?;
        if index == first {
            lead = Some(outcome);
        }
    }
    lead.ok_or_else(|| anyhow!("replica {first} gave no outcome"))
}

/// Rank 0 starts the orchestrator and waits for the other processes on the liveness channel;
/// the others join it. The processes must agree on the config, the run directory's checkpoint
/// and their device count.
fn join_group(
    cfg: &TrainConfig,
    run: &Path,
    opts: &TrainOptions,
    g: &ProcessGroup,
    local: usize,
    timeouts: Timeouts,
) -> Result<Liveness> {
    let latest = if opts.resume {
        crate::checkpoint::list_checkpoints(run)?
            .pop()
            .map(|c| c.step)
    } else {
        None
    };
    let identity = {
        let text = serde_json::json!({
            "config": serde_json::to_value(cfg).context("cannot serialise the config")?,
            "resume_from": latest,
            "resume": opts.resume,
            "stop_at": opts.stop_at,
        })
        .to_string();
        u64::from(crc32c::crc32c(text.as_bytes()))
    };
    let hello = Hello {
        rank: g.rank,
        devices: local,
        identity,
    };
    tracing::info!(
        "process {} of {} ({}): master {}:{}, this node {}",
        g.rank,
        g.size,
        g.source,
        g.master_addr,
        g.master_port,
        g.node_addr
    );
    if g.rank == 0 {
        collective::start_orchestrator(g.orchestrator_port())?;
        Liveness::serve(g.liveness_port(), g.size, hello, timeouts.join)
    } else {
        Liveness::join(
            &g.master_addr,
            g.liveness_port(),
            hello,
            g.size,
            timeouts.join,
        )
    }
}

/// Default limits: joining may wait for processes that start minutes apart; a step's
/// all-reduce waits only for the slowest replica's lag, and for replica 0's checkpoint.
pub fn default_timeouts(step_s: u64) -> Timeouts {
    Timeouts {
        join: Duration::from_secs(step_s.max(600)),
        step: Duration::from_secs(step_s),
    }
}
