//! Time per op group of a CREStereo training step and of a two-pass inference (Flex, CPU).
//!
//! Each group is measured in isolation, on random inputs of the exact shapes the network feeds
//! it, forward and backward separately (backward of `Σ out · R` for a random R), and multiplied
//! by its number of calls; the full step is measured too, so the table shows how much the
//! groups cover. Flex runs eagerly, so wall-clock timers around the calls are exact.
//!
//! ```sh
//! cargo run --release -p crestereo --features examples --example profile -- train 1 192 256 4
//! cargo run --release -p crestereo --features examples --example profile -- infer 256 320 20
//! ```
//!
//! `PROFILE_CLOCK=cpu` measures process CPU time instead of wall time (use it with
//! `RAYON_NUM_THREADS=1` on a shared machine).

use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use burn::tensor::Distribution;
use crestereo::network::attention::to_tokens;
use crestereo::network::encoder::instance_norm;
use crestereo::{
    AdaptiveGroupCorrelationConfig, CREStereo, CREStereoConfig, CpuAutodiffBackend, CpuBackend,
    SearchWindow, convex_upsample, resize_bilinear_align_corners, sequence_loss,
};

type A = CpuAutodiffBackend;
type P = CpuBackend;

fn rand<B: Backend, const D: usize>(shape: [usize; D]) -> Tensor<B, D> {
    Tensor::random(shape, Distribution::Normal(0.0, 1.0), &Default::default())
}

/// CPU seconds of this process (all threads). On a loaded machine this is steadier than wall
/// time; with RAYON_NUM_THREADS=1 it is the work done.
fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Seconds of `f`: CPU time with `PROFILE_CLOCK=cpu`, wall-clock time otherwise.
fn seconds<T>(f: impl FnOnce() -> T) -> (T, f64) {
    if std::env::var("PROFILE_CLOCK").is_ok_and(|v| v == "cpu") {
        let t = cpu_seconds();
        let out = f();
        return (out, cpu_seconds() - t);
    }
    let t = Instant::now();
    let out = f();
    (out, t.elapsed().as_secs_f64())
}

/// Forward and backward seconds of one call of `f` (training) or forward only (inference).
trait Measure: Backend {
    fn measure(f: &dyn Fn() -> Tensor<Self, 4>) -> (f64, f64);
}

impl Measure for A {
    fn measure(f: &dyn Fn() -> Tensor<A, 4>) -> (f64, f64) {
        let (out, fwd) = seconds(f);
        let r = rand::<A, 4>(out.dims());
        let loss = (out * r).sum();
        let (_, bwd) = seconds(|| loss.backward());
        (fwd, bwd)
    }
}

impl Measure for P {
    fn measure(f: &dyn Fn() -> Tensor<P, 4>) -> (f64, f64) {
        let (out, fwd) = seconds(f);
        drop(out);
        (fwd, 0.0)
    }
}

#[derive(Default)]
struct Table {
    rows: Vec<(String, f64, f64)>,
}

impl Table {
    /// Adds `calls` × the (best of 2) time of one call of `f` to `group`.
    fn add<B: Measure>(&mut self, group: &str, calls: usize, f: &dyn Fn() -> Tensor<B, 4>) {
        if calls == 0 {
            return;
        }
        let _ = B::measure(f); // warm-up (allocator, thread pool)
        let (fwd, bwd) = B::measure(f);
        let (fwd, bwd) = (fwd * calls as f64, bwd * calls as f64);
        match self.rows.iter_mut().find(|r| r.0 == group) {
            Some(r) => {
                r.1 += fwd;
                r.2 += bwd;
            }
            None => self.rows.push((group.to_string(), fwd, bwd)),
        }
    }

    fn print(&self, title: &str, total: (f64, f64, f64)) {
        let (fwd, bwd, rest) = total;
        let step = fwd + bwd + rest;
        println!(
            "\n{title}: measured step {step:.2} s (forward {fwd:.2}, backward {bwd:.2}, other {rest:.2})"
        );
        println!("| op group | forward s | backward s | share of step |");
        println!("|---|---:|---:|---:|");
        let (mut sf, mut sb) = (0.0, 0.0);
        for (g, f, b) in &self.rows {
            sf += f;
            sb += b;
            println!(
                "| {g} | {f:.3} | {b:.3} | {:.1} % |",
                100.0 * (f + b) / step
            );
        }
        if rest > 0.0 {
            println!("| Adam | | | {:.1} % |", 100.0 * rest / step);
        }
        println!(
            "| sum of groups (vs measured) | {sf:.3} ({fwd:.3}) | {sb:.3} ({bwd:.3}) | {:.1} % |",
            100.0 * (sf + sb + rest) / step
        );
    }
}

/// Encoder: the instance norms (+ ReLU) on their exact shapes, and the whole encoder; the
/// convolutions are the difference.
fn encoder<B: Measure>(t: &mut Table, m: &CREStereo<B>, n: usize, h: usize, w: usize) {
    let mut norms = Table::default();
    let norm = |c: usize, hh: usize, ww: usize| {
        let x = rand::<B, 4>([2 * n, c, hh, ww]).require_grad();
        move || burn::tensor::activation::relu(instance_norm(x.clone(), 1e-5))
    };
    norms.add::<B>("n", 7, &norm(64, h / 2, w / 2));
    norms.add::<B>("n", 6, &norm(96, h / 4, w / 4));
    norms.add::<B>("n", 6, &norm(128, h / 4, w / 4));
    let (nf, nb) = (norms.rows[0].1, norms.rows[0].2);
    let mut whole = Table::default();
    let (l, r) = (rand::<B, 4>([n, 3, h, w]), rand::<B, 4>([n, 3, h, w]));
    whole.add::<B>("e", 1, &|| {
        let (a, b) = m.fnet.forward_pair(l.clone(), r.clone());
        crestereo::cat(vec![a, b], 0)
    });
    let (ef, eb) = (whole.rows[0].1, whole.rows[0].2);
    t.rows.push((
        "encoder convolutions (+ residual adds)".into(),
        ef - nf,
        eb - nb,
    ));
    t.rows.push(("instance norms + ReLU".into(), nf, nb));
}

/// Every other group of the cascade: `l16`, `l8`, `l4` iterations at 1/16, 1/8, 1/4 of
/// (h, w); `full` predictions of (n, 2, h, w) upsampled at the end of the 1/16 and 1/8 levels.
#[allow(clippy::too_many_arguments)]
fn cascade<B: Measure>(
    t: &mut Table,
    m: &CREStereo<B>,
    n: usize,
    h: usize,
    w: usize,
    l16: usize,
    l8: usize,
    l4: usize,
) {
    let c = 256;
    let agcl = AdaptiveGroupCorrelationConfig::new().with_groups(4);
    let (h16, w16) = (h / 16, w / 16);
    if l16 > 0 {
        let (ta, tb) = (
            to_tokens(rand::<B, 4>([n, c, h16, w16])).require_grad(),
            to_tokens(rand::<B, 4>([n, c, h16, w16])).require_grad(),
        );
        let tokens = || (ta.clone(), tb.clone());
        t.add::<B>("attention (self + cross, LoFTR linear)", 1, &|| {
            let (a, b) = m.self_att_fn.forward_self(tokens().0, tokens().1);
            crestereo::cat(vec![a, b], 1).unsqueeze()
        });
        t.add::<B>("attention (self + cross, LoFTR linear)", l16, &|| {
            let (a, b) = m.cross_att_fn.forward_cross(tokens().0, tokens().1);
            crestereo::cat(vec![a, b], 1).unsqueeze()
        });
    }
    for (calls, div, warp) in [(l16, 16, false), (l8, 8, false), (l4, 4, true)] {
        let (hh, ww) = (h / div, w / div);
        let corr = agcl.init(
            rand::<B, 4>([n, c, hh, ww]).require_grad(),
            rand::<B, 4>([n, c, hh, ww]).require_grad(),
        );
        let flow_t = rand::<B, 4>([n, 2, hh, ww]).mul_scalar(2.0);
        let flow = || flow_t.clone();
        let off_t = rand::<B, 4>([n, 18, hh, ww]).tanh().require_grad();
        let (net_t, inp_t, cor_t) = (
            rand::<B, 4>([n, 128, hh, ww]).tanh().require_grad(),
            rand::<B, 4>([n, 128, hh, ww]).require_grad(),
            rand::<B, 4>([n, 36, hh, ww]).require_grad(),
        );
        let (fl_t, mask_t) = (
            rand::<B, 4>([n, 2, hh, ww]).require_grad(),
            rand::<B, 4>([n, 144, hh, ww]).require_grad(),
        );
        for (i, window) in [SearchWindow::Row1x9, SearchWindow::Square3x3]
            .into_iter()
            .enumerate()
        {
            let k = calls / 2 + if i == 0 { calls % 2 } else { 0 };
            if warp {
                t.add::<B>("AGCL correlation (sampling + group products)", k, &|| {
                    corr.corr_warp(flow(), window)
                });
            } else {
                t.add::<B>("AGCL correlation (sampling + group products)", k, &|| {
                    corr.corr_offset_maps(
                        corr.fmap1.clone(),
                        corr.fmap2.clone(),
                        flow(),
                        off_t.clone(),
                        window,
                    )
                });
            }
        }
        let ub = &m.update_block;
        t.add::<B>("update block (motion encoder, GRU, heads)", calls, &|| {
            let (net, mask, delta) =
                ub.forward(net_t.clone(), inp_t.clone(), cor_t.clone(), flow());
            crestereo::cat(vec![net, mask, delta], 1)
        });
        t.add::<B>("upsampling (convex + bilinear)", calls, &|| {
            let up = convex_upsample(fl_t.clone(), mask_t.clone(), 4);
            if div == 4 {
                up
            } else {
                resize_bilinear_align_corners(up, [h, w])
            }
        });
    }
}

fn train(n: usize, h: usize, w: usize, iters: usize) {
    let device = Default::default();
    let m = CREStereoConfig::new().init::<A>(&device);
    let mut t = Table::default();
    encoder(&mut t, &m, n, h, w);
    cascade(&mut t, &m, n, h, w, iters / 2, iters / 2, iters);
    let preds: Vec<Tensor<A, 4>> = (0..2 * iters)
        .map(|_| rand::<A, 4>([n, 2, h, w]).require_grad())
        .collect();
    let (disp, valid) = (rand::<A, 3>([n, h, w]), rand::<A, 3>([n, h, w]));
    t.add::<A>("loss", 1, &|| {
        sequence_loss(&preds, disp.clone(), valid.clone(), 0.9).reshape([1, 1, 1, 1])
    });
    // the full step, twice (the first warms up)
    let mut optim = AdamConfig::new().init();
    let mut model = m;
    let mut total = (0.0, 0.0, 0.0);
    for _ in 0..2 {
        let (loss, fwd) = seconds(|| {
            let preds = model.forward(
                rand([n, 3, h, w]).mul_scalar(255.0),
                rand([n, 3, h, w]).mul_scalar(255.0),
                iters,
                None,
            );
            sequence_loss(
                &preds,
                rand::<A, 3>([n, h, w]).abs(),
                Tensor::ones([n, h, w], &device),
                0.9,
            )
        });
        let (grads, bwd) = seconds(|| loss.backward());
        let (next, adam) = seconds(|| {
            let grads = GradientsParams::from_grads(grads, &model);
            optim.step(4e-4, model.clone(), grads)
        });
        model = next;
        total = (fwd, bwd, adam);
    }
    t.print(
        &format!(
            "training step, batch {n}, {h}x{w}, {iters} iterations, {} threads",
            threads()
        ),
        total,
    );
}

fn infer(h: usize, w: usize, iters: usize) {
    let device = Default::default();
    let m = CREStereoConfig::new().init::<P>(&device);
    let mut t = Table::default();
    // pass 1 at half size: the whole cascade; pass 2 at full size: encoder and the 1/4 level
    encoder(&mut t, &m, 1, h / 2, w / 2);
    cascade(&mut t, &m, 1, h / 2, w / 2, iters / 2, iters / 2, iters);
    encoder(&mut t, &m, 1, h, w);
    cascade(&mut t, &m, 1, h, w, 0, 0, iters);
    // merge the two passes' rows
    let mut merged = Table::default();
    for (g, f, b) in t.rows {
        match merged.rows.iter_mut().find(|r| r.0 == g) {
            Some(r) => {
                r.1 += f;
                r.2 += b;
            }
            None => merged.rows.push((g, f, b)),
        }
    }
    let mut total = 0.0;
    for _ in 0..2 {
        let l = rand::<P, 4>([1, 3, h, w]).mul_scalar(255.0);
        let r = rand::<P, 4>([1, 3, h, w]).mul_scalar(255.0);
        let (_, s) = seconds(|| {
            crestereo::infer::cascade(&m, l, r, crestereo::InferenceOptions { iters, stages: 2 })
        });
        total = s;
    }
    merged.print(
        &format!(
            "two-pass inference, {h}x{w}, {iters} iterations, {} threads",
            threads()
        ),
        (total, 0.0, 0.0),
    );
}

/// Throughput of one (m × k) · (k × n) float32 matrix product on Flex: the ceiling for the
/// convolutions, which are such products.
fn gemm(m: usize, k: usize, n: usize) {
    let a = rand::<P, 2>([m, k]);
    let b = rand::<P, 2>([k, n]);
    let _ = a.clone().matmul(b.clone());
    let (_, s) = seconds(|| a.clone().matmul(b.clone()).into_data());
    let (_, s2) = seconds(|| a.matmul(b).into_data());
    let s = s.min(s2);
    println!(
        "matmul {m}x{k} @ {k}x{n}: {s:.4} s, {:.1} GFLOP/s ({} threads)",
        2.0 * (m * k * n) as f64 / s / 1e9,
        threads()
    );
}

fn threads() -> String {
    std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all".into())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize, d: usize| {
        args.get(i)
            .map(|v| v.parse().expect("a number"))
            .unwrap_or(d)
    };
    match args.first().map(String::as_str) {
        Some("infer") => infer(num(1, 256), num(2, 320), num(3, 20)),
        Some("gemm") => gemm(num(1, 128), num(2, 1920), num(3, 3072)),
        _ => train(num(1, 1), num(2, 192), num(3, 256), num(4, 4)),
    }
}
