//! One replica of a data-parallel run: what it exchanges with the others each step (gradients
//! and the step's figures in one all-reduce), at start (rank 0's weights) and at checks (a
//! fingerprint of the weights, which must be the same everywhere).

use anyhow::{Result, bail};
use burn::module::AutodiffModule;
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;

use super::collective::Collective;
use super::flat;

/// A replica's place in the run and its link to the others.
pub struct Replica<B: AutodiffBackend> {
    /// 0..count; replica 0 writes logs and checkpoints.
    pub index: usize,
    pub count: usize,
    pub collective: Collective<B::InnerBackend>,
}

/// What a replica's passes of one step produced besides gradients.
#[derive(Debug, Clone, Default)]
pub struct StepFigures {
    /// The summed loss of its micro-batches (each already divided by the accumulation).
    pub loss: f64,
    /// A micro-batch's loss was not finite (its gradients are then not sent: zeros are).
    pub non_finite: bool,
    /// This replica was asked to stop (a signal).
    pub stop: bool,
    /// Per micro-batch: the summed absolute error of the last prediction over valid pixels, and
    /// the number of valid pixels.
    pub errors: Vec<(f64, f64)>,
}

/// The step as all replicas together took it.
pub struct SyncedStep {
    /// The mean of the replicas' gradients (`None` when the step is skipped).
    pub grads: Option<GradientsParams>,
    /// The mean of the replicas' losses: the loss of the global batch.
    pub loss: f64,
    /// Mean absolute error of the last prediction, per micro-batch over all replicas' valid
    /// pixels, averaged over the micro-batches (as a single device computes it).
    pub epe: f64,
    pub finite: bool,
    /// Some replica was asked to stop: all stop after this step.
    pub stop: bool,
}

impl<B: AutodiffBackend> Replica<B> {
    pub fn leads(&self) -> bool {
        self.index == 0
    }

    /// Averages the gradients and combines the figures of one step, in one all-reduce.
    pub fn sync_step<M: AutodiffModule<B>>(
        &self,
        model: &M,
        grads: Option<GradientsParams>,
        figures: &StepFigures,
        device: &B::Device,
    ) -> Result<SyncedStep> {
        let params = flat::parameter_count::<B, M>(model);
        let inner = device.clone();
        let send = match grads {
            Some(mut g) if !figures.non_finite => {
                flat::flatten_gradients::<B, M>(model, &mut g, device)
            }
            _ => Tensor::zeros([params], &inner),
        };
        let mut stats = vec![
            figures.loss as f32,
            f32::from(u8::from(figures.non_finite)),
            f32::from(u8::from(figures.stop)),
        ];
        for &(err, count) in &figures.errors {
            stats.extend([err as f32, count as f32]);
        }
        let stats_len = stats.len();
        let stats = Tensor::<B::InnerBackend, 1>::from_floats(stats.as_slice(), &inner);
        let summed = self
            .collective
            .sum(crestereo::cat(vec![send, stats], 0), "the step's gradients")?;
        let stats: Vec<f32> = summed
            .clone()
            .slice(params..params + stats_len)
            .into_data()
            .into_vec()
            .map_err(|e| anyhow::anyhow!("reading the step's figures: {e:?}"))?;
        let n = self.count as f64;
        let finite = stats[1] == 0.0;
        let micro = &stats[3..];
        let epe = micro
            .chunks_exact(2)
            .map(|p| {
                if p[1] > 0.0 {
                    f64::from(p[0]) / f64::from(p[1])
                } else {
                    f64::NAN
                }
            })
            .sum::<f64>()
            / (micro.len() / 2).max(1) as f64;
        let grads = finite.then(|| {
            let mean = summed.slice(0..params).div_scalar(self.count as f32);
            flat::unflatten_gradients::<B, M>(model, mean)
        });
        Ok(SyncedStep {
            grads,
            loss: f64::from(stats[0]) / n,
            epe,
            finite,
            stop: stats[2] > 0.0,
        })
    }

    /// Every replica's `values` (the same count on each): an all-gather through a sum, each
    /// replica filling its own slot. Exact for values below 2^48 (three 16-bit parts each).
    pub fn gather(&self, values: &[u64], device: &B::Device) -> Result<Vec<Vec<u64>>> {
        const PARTS: usize = 3;
        let k = values.len() * PARTS;
        let mut slots = vec![0f32; k * self.count];
        for (i, &v) in values.iter().enumerate() {
            if v >= 1 << 48 {
                bail!("value {v} too large to gather exactly");
            }
            for p in 0..PARTS {
                slots[self.index * k + i * PARTS + p] = ((v >> (16 * p)) & 0xFFFF) as f32;
            }
        }
        let inner = device.clone();
        let summed: Vec<f32> = self
            .collective
            .sum(
                Tensor::<B::InnerBackend, 1>::from_floats(slots.as_slice(), &inner),
                "a check of the replicas",
            )?
            .into_data()
            .into_vec()
            .map_err(|e| anyhow::anyhow!("reading the gathered values: {e:?}"))?;
        Ok(summed
            .chunks_exact(k)
            .map(|replica| {
                replica
                    .chunks_exact(PARTS)
                    .map(|parts| {
                        parts
                            .iter()
                            .enumerate()
                            .map(|(p, &x)| (x as u64) << (16 * p))
                            .sum()
                    })
                    .collect()
            })
            .collect())
    }

    /// Fails with `what` when the replicas' `values` differ.
    pub fn check_same(&self, what: &str, values: &[u64], device: &B::Device) -> Result<()> {
        let all = self.gather(values, device)?;
        if let Some((r, v)) = all.iter().enumerate().find(|(_, v)| **v != all[0]) {
            bail!(
                "replica {r} differs from replica 0 in {what} ({v:?} vs {:?})",
                all[0]
            );
        }
        Ok(())
    }

    /// The model with replica 0's weights on every replica (the others send zeros).
    pub fn share_weights<M: AutodiffModule<B>>(&self, model: M, device: &B::Device) -> Result<M> {
        let mine = flat::flatten_parameters::<B, M>(&model).inner();
        let send = if self.leads() {
            mine
        } else {
            mine.zeros_like()
        };
        let shared = self.collective.sum(send, "replica 0's weights")?;
        let shared = Tensor::<B, 1>::from_inner(shared).to_device(device);
        Ok(flat::load_flat_parameters::<B, M>(model, shared))
    }
}

/// A 48-bit fingerprint of a model's weights (CRC-32C of their bytes, with the count).
pub fn weights_fingerprint<B: Backend, M: burn::module::Module<B>>(model: &M) -> Result<u64> {
    let values: Vec<f32> = flat::flatten_parameters::<B, M>(model)
        .into_data()
        .convert::<f32>()
        .into_vec()
        .map_err(|e| anyhow::anyhow!("reading the weights: {e:?}"))?;
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    Ok((u64::from(crc32c::crc32c(&bytes)) << 16) ^ (values.len() as u64 & 0xFFFF))
}
