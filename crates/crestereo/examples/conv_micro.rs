//! One convolution of the shapes the network runs, forward and backward on `Autodiff<Flex>`
//! and the inference forward on `Flex`, through `crestereo::ops::conv2d`, next to a plain matrix
//! product with the same FLOPs (the rate the GEMM kernel reaches on this machine): how far a
//! convolution is from its GEMM.
//!
//! ```sh
//! cargo run --release -p crestereo --features examples --example conv_micro -- 2 384 96 128 128 1x5 5
//! #                                                      N Cin  H   W Cout kernel repeats
//! ```

use std::time::Instant;

use burn::module::AutodiffModule;
use burn::nn::PaddingConfig2d;
use burn::prelude::*;
use burn::tensor::Distribution;
use crestereo::ops::conv2d::Conv2dConfig;
use crestereo::{CpuAutodiffBackend, CpuBackend};

type A = CpuAutodiffBackend;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize, d: usize| a.get(i).map_or(d, |s| s.parse().expect("a number"));
    let (n, cin, h, w, cout) = (num(0, 2), num(1, 384), num(2, 96), num(3, 128), num(4, 128));
    let kernel = a.get(5).map_or("1x5", String::as_str);
    let (kh, kw) = kernel
        .split_once('x')
        .map(|(a, b)| (a.parse::<usize>().unwrap(), b.parse::<usize>().unwrap()))
        .expect("kernel as HxW");
    let repeats = num(6, 5);
    let device = Default::default();
    let conv = Conv2dConfig::new([cin, cout], [kh, kw])
        .with_padding(PaddingConfig2d::Explicit(kh / 2, kw / 2, kh / 2, kw / 2))
        .init::<A>(&device);
    let x = Tensor::<A, 4>::random([n, cin, h, w], Distribution::Normal(0.0, 1.0), &device)
        .require_grad();
    let r = Tensor::<A, 4>::random([n, cout, h, w], Distribution::Normal(0.0, 1.0), &device);
    let flops = 2.0 * (n * cout * cin * kh * kw * h * w) as f64;

    let (mut fwd, mut bwd) = (vec![], vec![]);
    for _ in 0..repeats {
        let t = Instant::now();
        let y = conv.forward(x.clone());
        let _ = y.clone().into_data();
        fwd.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let g = (y * r.clone()).sum().backward();
        let _ = x.grad(&g).unwrap().into_data();
        bwd.push(t.elapsed().as_secs_f64());
    }
    // Inference: the same convolution on plain Flex (no autodiff; its own Winograd tiles).
    let (conv_i, x_i) = (conv.valid(), x.clone().inner());
    let mut inf = vec![];
    for _ in 0..repeats {
        let t = Instant::now();
        let _ = conv_i.forward(x_i.clone()).into_data();
        inf.push(t.elapsed().as_secs_f64());
    }
    // The same FLOPs as one matrix product (cout × cin·kh·kw) · (cin·kh·kw × n·h·w).
    let lhs =
        Tensor::<CpuBackend, 2>::random([cout, cin * kh * kw], Distribution::Default, &device);
    let rhs =
        Tensor::<CpuBackend, 2>::random([cin * kh * kw, n * h * w], Distribution::Default, &device);
    let mut mm = vec![];
    for _ in 0..repeats {
        let t = Instant::now();
        let _ = lhs.clone().matmul(rhs.clone()).into_data();
        mm.push(t.elapsed().as_secs_f64());
    }
    let (f, b, m, i) = (median(fwd), median(bwd), median(mm), median(inf));
    println!(
        "conv {n}x{cin}x{h}x{w} -> {cout}, {kh}x{kw}: inference {:.1} ms ({:.1} GFLOP/s), training forward {:.1} ms ({:.1} GFLOP/s), backward {:.1} ms ({:.1} GFLOP/s); GEMM of the same size {:.1} ms ({:.1} GFLOP/s); forward/GEMM {:.2}, backward/(2 GEMM) {:.2}",
        i * 1e3,
        flops / i / 1e9,
        f * 1e3,
        flops / f / 1e9,
        b * 1e3,
        2.0 * flops / b / 1e9,
        m * 1e3,
        flops / m / 1e9,
        f / m,
        b / (2.0 * m)
    );
}
