//! Kernel against composed time per op on Flex (CPU): what a backend without kernels pays.
//!
//! Each op runs on random inputs of the shapes it has in a training step at the paper's crop
//! (batch 1, 384×512: 1/4 = 96×128, 1/8 = 48×64), once with the hand-written kernels and once
//! with every kernel switched off (`dispatch::use_composed_ops`), interleaved, median of
//! `REPEATS` (default 5): inference forward on plain Flex, forward + backward of `Σ out · R`
//! on `Autodiff<Flex>`.
//!
//! ```sh
//! cargo run --release -p crestereo --features examples --example kernels_vs_composed [-- REPEATS]
//! ```

use std::time::Instant;

use burn::prelude::*;
use burn::tensor::Distribution;
use crestereo::ops::agcl::{self, CorrSpec};
use crestereo::ops::conv2d::Conv2dConfig;
use crestereo::ops::dispatch::use_composed_ops;
use crestereo::{
    CpuAutodiffBackend, CpuBackend, SearchWindow, SepConvGru, SepConvGruConfig, convex_upsample,
};

type A = CpuAutodiffBackend;
type P = CpuBackend;

fn rand<B: Backend, const D: usize>(shape: [usize; D]) -> Tensor<B, D> {
    Tensor::random(shape, Distribution::Normal(0.0, 1.0), &Default::default())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Seconds of `f`, its result read back (Flex is eager: the read only waits for nothing).
fn time<const D: usize, B: Backend>(f: &dyn Fn() -> Tensor<B, D>) -> f64 {
    let t = Instant::now();
    let _ = f().into_data();
    t.elapsed().as_secs_f64()
}

/// Forward + backward seconds of `Σ f(inputs) · R`.
fn time_train<const D: usize>(
    inputs: &[Tensor<A, 4>],
    f: &dyn Fn(&[Tensor<A, 4>]) -> Tensor<A, D>,
) -> f64 {
    let t = Instant::now();
    let xs: Vec<_> = inputs.iter().map(|x| x.clone().require_grad()).collect();
    let out = f(&xs);
    let r = Tensor::<A, D>::random(
        out.dims(),
        Distribution::Normal(0.0, 1.0),
        &Default::default(),
    );
    let grads = (out * r).sum().backward();
    for x in &xs {
        let _ = x.grad(&grads).map(|g| g.into_data());
    }
    t.elapsed().as_secs_f64()
}

struct Row {
    name: &'static str,
    kernel: Vec<f64>,
    composed: Vec<f64>,
}

fn measure(name: &'static str, repeats: usize, run: &dyn Fn() -> f64) -> Row {
    let mut row = Row {
        name,
        kernel: vec![],
        composed: vec![],
    };
    // warm-up of both paths (scratch pools, page faults)
    for composed in [false, true] {
        use_composed_ops(composed);
        run();
    }
    for _ in 0..repeats {
        for composed in [false, true] {
            use_composed_ops(composed);
            let s = run();
            if composed {
                &mut row.composed
            } else {
                &mut row.kernel
            }
            .push(s);
        }
    }
    use_composed_ops(false);
    row
}

fn gru<B: Backend>() -> SepConvGru<B> {
    SepConvGruConfig::new().init(&Default::default())
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .map_or(5, |s| s.parse().expect("REPEATS as a number"));
    let (h4, w4, h8, w8) = (96, 128, 48, 64);
    let spec = CorrSpec::new(SearchWindow::Row1x9, 4);
    let k = spec.candidates();
    let corr_inputs = |h, w| -> Vec<Tensor<A, 4>> {
        vec![
            rand([1, 256, h, w]),
            rand([1, 256, h, w]),
            rand::<A, 4>([1, 2, h, w]).mul_scalar(3.0),
            rand::<A, 4>([1, 2 * k, h, w]).mul_scalar(0.5),
        ]
    };
    let c8 = corr_inputs(h8, w8);
    let c4 = corr_inputs(h4, w4);
    let conv = Conv2dConfig::new([256, 192], [3, 3])
        .with_padding(burn::nn::PaddingConfig2d::Explicit(1, 1, 1, 1))
        .init::<A>(&Default::default());
    let conv_p = burn::module::AutodiffModule::valid(&conv);
    let gru_a = gru::<A>();
    let gru_p = burn::module::AutodiffModule::valid(&gru_a);
    let gru_in: Vec<Tensor<A, 4>> = vec![rand([1, 128, h4, w4]), rand([1, 256, h4, w4])];
    let up_in: Vec<Tensor<A, 4>> = vec![rand([1, 2, h4, w4]), rand([1, 144, h4, w4])];
    let inner =
        |v: &[Tensor<A, 4>]| -> Vec<Tensor<P, 4>> { v.iter().map(|t| t.clone().inner()).collect() };
    let (c8p, c4p, gru_inp, up_inp) = (inner(&c8), inner(&c4), inner(&gru_in), inner(&up_in));
    let x4p: Tensor<P, 4> = rand([1, 256, h4, w4]);
    let x4: Vec<Tensor<A, 4>> = vec![rand([1, 256, h4, w4])];

    let rows = [
        measure("AGCL offset corr 1/8, inference", repeats, &|| {
            time(&|| {
                agcl::offset_corr(
                    c8p[0].clone(),
                    c8p[1].clone(),
                    c8p[2].clone(),
                    c8p[3].clone(),
                    spec,
                )
            })
        }),
        measure("AGCL offset corr 1/8, fwd+bwd", repeats, &|| {
            time_train(&c8, &|x| {
                agcl::offset_corr(x[0].clone(), x[1].clone(), x[2].clone(), x[3].clone(), spec)
            })
        }),
        measure("AGCL warp + shift corr 1/4, inference", repeats, &|| {
            time(&|| {
                agcl::shift_corr(
                    c4p[0].clone(),
                    agcl::warp(c4p[1].clone(), c4p[2].clone()),
                    spec,
                )
            })
        }),
        measure("AGCL warp + shift corr 1/4, fwd+bwd", repeats, &|| {
            time_train(&c4, &|x| {
                agcl::shift_corr(x[0].clone(), agcl::warp(x[1].clone(), x[2].clone()), spec)
            })
        }),
        measure("conv 3x3 256->192 at 1/4, inference", repeats, &|| {
            time(&|| conv_p.forward(x4p.clone()))
        }),
        measure("conv 3x3 256->192 at 1/4, fwd+bwd", repeats, &|| {
            time_train(&x4, &|x| conv.forward(x[0].clone()))
        }),
        measure("SepConvGRU step at 1/4, inference", repeats, &|| {
            time(&|| gru_p.forward(gru_inp[0].clone(), gru_inp[1].clone()))
        }),
        measure("SepConvGRU step at 1/4, fwd+bwd", repeats, &|| {
            time_train(&gru_in, &|x| gru_a.forward(x[0].clone(), x[1].clone()))
        }),
        measure("convex upsampling x4 of 1/4, inference", repeats, &|| {
            time(&|| convex_upsample(up_inp[0].clone(), up_inp[1].clone(), 4))
        }),
        measure("convex upsampling x4 of 1/4, fwd+bwd", repeats, &|| {
            time_train(&up_in, &|x| convex_upsample(x[0].clone(), x[1].clone(), 4))
        }),
    ];
    println!(
        "kernels vs composed ops on Flex, batch 1 at the paper crop's level sizes, {} threads, median of {repeats}",
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all".into())
    );
    println!("| op | kernel ms | composed ms | composed / kernel |");
    println!("|---|---:|---:|---:|");
    for r in rows {
        let (k, c) = (median(r.kernel) * 1e3, median(r.composed) * 1e3);
        println!("| {} | {k:.1} | {c:.1} | {:.2}x |", r.name, c / k);
    }
}
