//! Temporary: one update-block call at a given size, median of 7 (Flex, plain).
use std::time::Instant;

use burn::prelude::*;
use burn::tensor::Distribution;
use crestereo::{CREStereoConfig, CpuBackend};

type P = CpuBackend;

fn main() {
    let a: Vec<usize> = std::env::args()
        .skip(1)
        .map(|s| s.parse().unwrap())
        .collect();
    let (h, w) = (a[0], a[1]);
    let d = Default::default();
    let m = CREStereoConfig::new().init::<P>(&d);
    let r = |c: usize| Tensor::<P, 4>::random([1, c, h, w], Distribution::Normal(0.0, 1.0), &d);
    let (net, inp, corr, flow) = (r(128).tanh(), r(128), r(36), r(2));
    let mut ts = Vec::new();
    for i in 0..9 {
        let t = Instant::now();
        let (n, mk, df) =
            m.update_block
                .forward(net.clone(), inp.clone(), corr.clone(), flow.clone());
        let _ = (n, mk, df);
        if i >= 2 {
            ts.push(t.elapsed().as_secs_f64());
        }
    }
    ts.sort_by(f64::total_cmp);
    println!(
        "burn update {h}x{w}: median {:.1} ms min {:.1}",
        ts[3] * 1e3,
        ts[0] * 1e3
    );
}
