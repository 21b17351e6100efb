//! Checks of the AGCL ops on any backend, shared by the Flex tests (`tests/integration/agcl.rs`) and the
//! Vulkan tests (`crestereo-train/tests/vulkan.rs`): the dispatched op (the backend's kernel,
//! or the composed ops where it has none) and the composed ops of `agcl::composed` against the
//! historical implementation kept here as the reference (it reads coordinates on the host and
//! builds gather indices there: independent of both), gradients against Burn's autodiff of that
//! reference, and central finite differences of the kernel's own backward.

use burn::prelude::*;
use burn::tensor::TensorData;
use burn::tensor::backend::AutodiffBackend;
use crestereo::SearchWindow;
use crestereo::ops::agcl::{self, CorrSpec, composed};

/// The device a test runs a backend on.
pub trait TestDevice: Backend {
    fn test_device() -> Self::Device;
}

impl TestDevice for burn::backend::Flex {
    fn test_device() -> Self::Device {
        Default::default()
    }
}

impl TestDevice for burn::backend::Autodiff<burn::backend::Flex> {
    fn test_device() -> Self::Device {
        Default::default()
    }
}

/// lavapipe, Mesa's CPU implementation of Vulkan, which wgpu lists as a CPU adapter: the GPU
/// path's device in CI.
#[cfg(feature = "wgpu")]
pub const LAVAPIPE: burn::backend::wgpu::WgpuDevice = burn::backend::wgpu::WgpuDevice::Cpu;

#[cfg(feature = "wgpu")]
impl TestDevice for burn::backend::Wgpu {
    fn test_device() -> Self::Device {
        LAVAPIPE
    }
}

#[cfg(feature = "wgpu")]
impl TestDevice for burn::backend::Autodiff<burn::backend::Wgpu> {
    fn test_device() -> Self::Device {
        LAVAPIPE
    }
}

/// The former `corr::bilinear_sample_points`: coordinates read on the host, gather indices
/// built there, four `select`s and a weighted sum. Returns (N, P, C).
pub fn reference_sample_points<B: Backend>(
    img: Tensor<B, 4>,
    x: Tensor<B, 2>,
    y: Tensor<B, 2>,
) -> Tensor<B, 3> {
    let [n, c, h, w] = img.dims();
    let [_, p] = x.dims();
    let device = img.device();
    let table = crestereo::cat(
        vec![
            img.permute([0, 2, 3, 1]).reshape([n * h * w, c]),
            Tensor::zeros([1, c], &device),
        ],
        0,
    );
    let zero_row = (n * h * w) as i64;
    // Read to the host by hand, not through `values`: the host-read scan of
    // crestereo's `agcl::host_read_scan_detects_the_replaced_sampler` must find these two reads.
    let xs: Vec<f32> = x
        .clone()
        .detach()
        .into_data()
        .convert::<f32>()
        .into_vec()
        .unwrap();
    let ys: Vec<f32> = y
        .clone()
        .detach()
        .into_data()
        .convert::<f32>()
        .into_vec()
        .unwrap();
    let np = n * p;
    let mut x0f = vec![0f32; np];
    let mut y0f = vec![0f32; np];
    let mut idx = vec![0i64; 4 * np];
    for b in 0..n {
        for q in 0..p {
            let i = b * p + q;
            let fx = xs[i].floor();
            let fy = ys[i].floor();
            x0f[i] = fx;
            y0f[i] = fy;
            let base = (b * h * w) as i64;
            let at = |xx: f32, yy: f32| -> i64 {
                if xx >= 0.0 && yy >= 0.0 && xx <= (w - 1) as f32 && yy <= (h - 1) as f32 {
                    base + yy as i64 * w as i64 + xx as i64
                } else {
                    zero_row
                }
            };
            idx[i] = at(fx, fy);
            idx[np + i] = at(fx + 1.0, fy);
            idx[2 * np + i] = at(fx, fy + 1.0);
            idx[3 * np + i] = at(fx + 1.0, fy + 1.0);
        }
    }
    let x0 = Tensor::<B, 2>::from_data(TensorData::new(x0f, [n, p]), &device);
    let y0 = Tensor::<B, 2>::from_data(TensorData::new(y0f, [n, p]), &device);
    let wx1 = x - x0;
    let wy1 = y - y0;
    let wx0 = wx1.clone().neg().add_scalar(1.0);
    let wy0 = wy1.clone().neg().add_scalar(1.0);
    let weights = crestereo::cat(
        vec![
            wx0.clone() * wy0.clone(),
            wx1.clone() * wy0,
            wx0 * wy1.clone(),
            wx1 * wy1,
        ],
        0,
    )
    .reshape([4, np, 1]);
    let idx = Tensor::<B, 1, Int>::from_data(TensorData::new(idx, [4 * np]), &device);
    let corners = table.select(0, idx).reshape([4, np, c]);
    (corners * weights).sum_dim(0).reshape([n, p, c])
}

fn pixel_grid<B: Backend>(h: usize, w: usize, device: &B::Device) -> (Tensor<B, 4>, Tensor<B, 4>) {
    let gx: Vec<f32> = (0..h * w).map(|i| (i % w) as f32).collect();
    let gy: Vec<f32> = (0..h * w).map(|i| (i / w) as f32).collect();
    (
        Tensor::from_data(TensorData::new(gx, [1, 1, h, w]), device),
        Tensor::from_data(TensorData::new(gy, [1, 1, h, w]), device),
    )
}

/// The former `corr_offset_maps`.
fn reference_offset_corr<B: Backend>(
    left: Tensor<B, 4>,
    right: Tensor<B, 4>,
    flow: Tensor<B, 4>,
    extra_offset: Tensor<B, 4>,
    window: SearchWindow,
    groups: usize,
) -> Tensor<B, 4> {
    let [n, c, h, w] = left.dims();
    let device = left.device();
    let offsets = window.offsets();
    let k = offsets.len();
    let extra = extra_offset.reshape([n, k, 2, h, w]);
    let off_x = extra
        .clone()
        .slice([0..n, 0..k, 0..1, 0..h, 0..w])
        .reshape([n, k, h, w]);
    let off_y = extra
        .slice([0..n, 0..k, 1..2, 0..h, 0..w])
        .reshape([n, k, h, w]);
    let dx: Vec<f32> = offsets.iter().map(|o| o.0 as f32).collect();
    let dy: Vec<f32> = offsets.iter().map(|o| o.1 as f32).collect();
    let dx = Tensor::<B, 4>::from_data(TensorData::new(dx, [1, k, 1, 1]), &device);
    let dy = Tensor::<B, 4>::from_data(TensorData::new(dy, [1, k, 1, 1]), &device);
    let (gx, gy) = pixel_grid::<B>(h, w, &device);
    let fx = flow.clone().slice([0..n, 0..1, 0..h, 0..w]);
    let fy = flow.slice([0..n, 1..2, 0..h, 0..w]);
    let x = (gx + fx + dx + off_x).reshape([n, k * h * w]);
    let y = (gy + fy + dy + off_y).reshape([n, k * h * w]);
    let sampled = reference_sample_points(right, x, y).reshape([n, k, h, w, c]);
    let left = left.permute([0, 2, 3, 1]).reshape([n, 1, h, w, c]);
    let corr = (left * sampled)
        .reshape([n, k, h, w, groups, c / groups])
        .mean_dim(5)
        .reshape([n, k, h, w, groups]);
    corr.permute([0, 4, 1, 2, 3]).reshape([n, groups * k, h, w])
}

/// The former warp inside `corr_warp`.
fn reference_warp<B: Backend>(right: Tensor<B, 4>, flow: Tensor<B, 4>) -> Tensor<B, 4> {
    let [n, c, h, w] = right.dims();
    let (gx, gy) = pixel_grid::<B>(h, w, &right.device());
    let fx = flow.clone().slice([0..n, 0..1, 0..h, 0..w]);
    let fy = flow.slice([0..n, 1..2, 0..h, 0..w]);
    let x = (gx + fx).reshape([n, h * w]);
    let y = (gy + fy).reshape([n, h * w]);
    reference_sample_points(right, x, y)
        .reshape([n, h, w, c])
        .permute([0, 3, 1, 2])
}

/// The former shift part of `corr_warp`: edge pad, nine crops, products, group means.
fn reference_shift_corr<B: Backend>(
    left: Tensor<B, 4>,
    warped: Tensor<B, 4>,
    window: SearchWindow,
    g: usize,
) -> Tensor<B, 4> {
    let [n, c, h, w] = left.dims();
    let (ry, rx) = window.radius();
    let padded = warped.pad((rx, rx, ry, ry), burn::tensor::ops::PadMode::Edge);
    let mut corrs = Vec::new();
    for (dx, dy) in window.offsets() {
        let oy = (dy + ry as i64) as usize;
        let ox = (dx + rx as i64) as usize;
        let crop = padded.clone().slice([0..n, 0..c, oy..oy + h, ox..ox + w]);
        let prod = (left.clone() * crop).reshape([n, g, c / g, h, w]);
        corrs.push(prod.mean_dim(2));
    }
    crestereo::cat(corrs, 2).reshape([n, g * window.offsets().len(), h, w])
}

fn values<B: Backend, const D: usize>(t: Tensor<B, D>) -> Vec<f32> {
    t.into_data().convert::<f32>().into_vec().unwrap()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

struct Inputs {
    left: Vec<f32>,
    right: Vec<f32>,
    flow: Vec<f32>,
    offset: Vec<f32>,
    k: usize,
}

/// Random features and sampling positions that reach past every border (about a third of the
/// candidates have at least one corner outside). With `away_from_integers`, every sampling
/// coordinate has a fractional part in [0.25, 0.75] (finite differences then stay on one
/// bilinear patch).
fn inputs(dims: [usize; 4], window: SearchWindow, seed: u64, away_from_integers: bool) -> Inputs {
    let [n, c, h, w] = dims;
    let k = window.offsets().len();
    let mut state = seed;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as f64 / (1u64 << 31) as f64) as f32 // [0, 1)
    };
    let left: Vec<f32> = (0..n * c * h * w).map(|_| next() * 2.0 - 1.0).collect();
    let right: Vec<f32> = (0..n * c * h * w).map(|_| next() * 2.0 - 1.0).collect();
    // integer flow plus fractional learned offsets: positions x + flow + dx + off
    let mut flow = vec![0f32; n * 2 * h * w];
    for v in flow.iter_mut() {
        *v = (next() * 6.0 - 3.0).round();
    }
    let mut offset = vec![0f32; n * 2 * k * h * w];
    for v in offset.iter_mut() {
        *v = if away_from_integers {
            next() * 0.5 + 0.25
        } else {
            next() * 2.0 - 1.0
        };
    }
    if !away_from_integers {
        // some exactly integer positions and some far outside
        for i in (0..offset.len()).step_by(7) {
            offset[i] = 0.0;
        }
        for i in (0..flow.len()).step_by(11) {
            flow[i] = 40.0;
        }
    }
    Inputs {
        left,
        right,
        flow,
        offset,
        k,
    }
}

fn t4<B: TestDevice>(data: &[f32], shape: [usize; 4]) -> Tensor<B, 4> {
    Tensor::from_data(TensorData::new(data.to_vec(), shape), &B::test_device())
}

/// The offset correlation's forward: the dispatched op and the composed ops against the
/// reference (≤ 1e-6: same arithmetic up to summation order).
pub fn offset_corr_forward<B: TestDevice>() {
    for (window, dims) in [
        (SearchWindow::Row1x9, [2, 16, 6, 9]),
        (SearchWindow::Square3x3, [1, 12, 7, 5]),
    ] {
        let groups = 4;
        let x = inputs(dims, window, 7, false);
        let [n, _, h, w] = dims;
        let f = |v: &Vec<f32>, s| t4::<B>(v, s);
        let (l, r) = (f(&x.left, dims), f(&x.right, dims));
        let (fl, of) = (f(&x.flow, [n, 2, h, w]), f(&x.offset, [n, 2 * x.k, h, w]));
        let spec = CorrSpec::new(window, groups);
        let reference = values(reference_offset_corr(
            l.clone(),
            r.clone(),
            fl.clone(),
            of.clone(),
            window,
            groups,
        ));
        for (label, out) in [
            (
                "dispatched",
                agcl::offset_corr(l.clone(), r.clone(), fl.clone(), of.clone(), spec),
            ),
            (
                "composed",
                composed::offset_corr(l.clone(), r.clone(), fl.clone(), of.clone(), spec),
            ),
        ] {
            assert_eq!(out.dims(), [n, groups * x.k, h, w]);
            let err = max_abs_diff(&values(out), &reference);
            println!("{window:?} {label}: max |op - reference| = {err:.3e}");
            assert!(err <= 1e-6, "{window:?} {label}: {err}");
        }
    }
}

/// The warp's forward, dispatched and composed, against the reference.
pub fn warp_forward<B: TestDevice>() {
    let dims = [2, 5, 6, 9];
    let x = inputs(dims, SearchWindow::Row1x9, 3, false);
    let [n, _, h, w] = dims;
    let r = t4::<B>(&x.right, dims);
    let fl = t4::<B>(&x.flow, [n, 2, h, w]).add_scalar(0.37);
    let reference = values(reference_warp(r.clone(), fl.clone()));
    for (label, out) in [
        ("dispatched", agcl::warp(r.clone(), fl.clone())),
        ("composed", composed::warp(r.clone(), fl.clone())),
    ] {
        let err = max_abs_diff(&values(out), &reference);
        println!("warp {label}: max |op - reference| = {err:.3e}");
        assert!(err <= 1e-6, "warp {label}: {err}");
    }
}

/// The shifted correlation (forward and gradients), dispatched and composed, against the
/// reference. `A`: the autodiff backend the gradients are taken on.
pub fn shift_corr_forward_and_gradients<B: TestDevice, A: TestDevice + AutodiffBackend>() {
    let groups = 4;
    for (window, dims) in [
        (SearchWindow::Row1x9, [2, 8, 5, 7]),
        (SearchWindow::Square3x3, [1, 12, 6, 4]),
    ] {
        let x = inputs(dims, window, 41, false);
        let spec = CorrSpec::new(window, groups);
        let (l, r) = (t4::<B>(&x.left, dims), t4::<B>(&x.right, dims));
        let reference = values(reference_shift_corr(l.clone(), r.clone(), window, groups));
        for (label, out) in [
            ("dispatched", agcl::shift_corr(l.clone(), r.clone(), spec)),
            ("composed", composed::shift_corr(l.clone(), r.clone(), spec)),
        ] {
            let err = max_abs_diff(&values(out), &reference);
            println!("shift {window:?} {label}: max |op - reference| = {err:.3e}");
            assert!(err <= 1e-6, "{window:?} {label}: {err}");
        }
        let [n, _, h, w] = dims;
        let weights = output_weights::<A>([n, groups * x.k, h, w], window, 43);
        let grads_of = |which: Impl| -> Vec<Vec<f32>> {
            let l = t4::<A>(&x.left, dims).require_grad();
            let r = t4::<A>(&x.right, dims).require_grad();
            let out = match which {
                Impl::Dispatched => agcl::shift_corr(l.clone(), r.clone(), spec),
                Impl::Composed => composed::shift_corr(l.clone(), r.clone(), spec),
                Impl::Reference => reference_shift_corr(l.clone(), r.clone(), window, groups),
            };
            let g = (out * weights.clone()).sum().backward();
            [l, r].iter().map(|t| values(t.grad(&g).unwrap())).collect()
        };
        assert_gradients_match(&format!("shift {window:?}"), &["left", "warped"], grads_of);
    }
}

/// Random weights of an op's output, of shape `dims`, so that the scalar a gradient check
/// differentiates depends on every output element.
fn output_weights<A: TestDevice>(
    dims: [usize; 4],
    window: SearchWindow,
    seed: u64,
) -> Tensor<A, 4> {
    t4::<A>(&inputs(dims, window, seed, false).left, dims)
}

/// The gradients of the dispatched op and of the composed ops against those of the reference:
/// each input's within 1e-5 of the reference gradient's largest magnitude (at least 1).
fn assert_gradients_match(label: &str, names: &[&str], grads_of: impl Fn(Impl) -> Vec<Vec<f32>>) {
    let reference = grads_of(Impl::Reference);
    for which in [Impl::Dispatched, Impl::Composed] {
        let grads = grads_of(which);
        assert_eq!(grads.len(), names.len());
        for (name, (a, b)) in names.iter().zip(grads.iter().zip(&reference)) {
            let err = max_abs_diff(a, b) / b.iter().fold(1f32, |m, v| m.max(v.abs()));
            println!("{label} {which:?} d/d{name}: scaled max diff {err:.3e}");
            assert!(err <= 1e-5, "{label} {which:?} d/d{name}: {err}");
        }
    }
}

/// Which implementation of an op a gradient check runs.
#[derive(Clone, Copy, Debug)]
enum Impl {
    /// `agcl::*`: the backend's kernel with its own backward (or the composed ops).
    Dispatched,
    /// `agcl::composed::*`, differentiated by autodiff.
    Composed,
    /// The historical implementation above, differentiated by autodiff.
    Reference,
}

/// Gradients of the offset correlation and the warp w.r.t. every input, dispatched (the
/// kernels' own backward) and composed, against Burn's autodiff of the reference.
pub fn offset_corr_and_warp_gradients<A: TestDevice + AutodiffBackend>() {
    let groups = 4;
    for (window, dims) in [
        (SearchWindow::Row1x9, [2, 8, 5, 7]),
        (SearchWindow::Square3x3, [1, 8, 6, 6]),
    ] {
        let x = inputs(dims, window, 11, false);
        let [n, _, h, w] = dims;
        let weights = output_weights::<A>([n, groups * x.k, h, w], window, 5);
        let grads_of = |which: Impl| -> Vec<Vec<f32>> {
            let l = t4::<A>(&x.left, dims).require_grad();
            let r = t4::<A>(&x.right, dims).require_grad();
            let fl = t4::<A>(&x.flow, [n, 2, h, w])
                .add_scalar(0.1)
                .require_grad();
            let of = t4::<A>(&x.offset, [n, 2 * x.k, h, w]).require_grad();
            let (l2, r2, f2, o2) = (l.clone(), r.clone(), fl.clone(), of.clone());
            let spec = CorrSpec::new(window, groups);
            let out = match which {
                Impl::Dispatched => agcl::offset_corr(l2, r2, f2, o2, spec),
                Impl::Composed => composed::offset_corr(l2, r2, f2, o2, spec),
                Impl::Reference => reference_offset_corr(l2, r2, f2, o2, window, groups),
            };
            let g = (out * weights.clone()).sum().backward();
            [l, r, fl, of]
                .iter()
                .map(|t| values(t.grad(&g).expect("gradient")))
                .collect()
        };
        let names = ["left", "right", "flow", "offset"];
        assert_gradients_match(&format!("{window:?}"), &names, grads_of);
    }

    // warp: gradients w.r.t. the map and the flow
    let dims = [2, 5, 6, 7];
    let x = inputs(dims, SearchWindow::Row1x9, 13, false);
    let [n, c, h, w] = dims;
    let weights = t4::<A>(
        &inputs(dims, SearchWindow::Row1x9, 17, false).left,
        [n, c, h, w],
    );
    let grads_of = |which: Impl| -> Vec<Vec<f32>> {
        let r = t4::<A>(&x.right, dims).require_grad();
        let fl = t4::<A>(&x.flow, [n, 2, h, w])
            .add_scalar(0.3)
            .require_grad();
        let out = match which {
            Impl::Dispatched => agcl::warp(r.clone(), fl.clone()),
            Impl::Composed => composed::warp(r.clone(), fl.clone()),
            Impl::Reference => reference_warp(r.clone(), fl.clone()),
        };
        let g = (out * weights.clone()).sum().backward();
        [r, fl]
            .iter()
            .map(|t| values(t.grad(&g).unwrap()))
            .collect()
    };
    assert_gradients_match("warp", &["right", "flow"], grads_of);
}

/// Central finite differences of `L = Σ out · W` along random directions, one input at a time,
/// against the analytic gradients of the backward kernel. Sampling coordinates keep their
/// fractional parts in [0.25, 0.75] and the coordinate step is ≤ 0.01 px, so every difference
/// stays on one bilinear patch; L is evaluated in float64 from the float32 outputs.
/// (`B` must have AGCL kernels: the analytic gradients are its backward kernel's.)
pub fn offset_corr_finite_differences<B: TestDevice>() {
    let groups = 2;
    for window in [SearchWindow::Row1x9, SearchWindow::Square3x3] {
        let dims = [1, 6, 5, 8];
        let [n, _, h, w] = dims;
        let x = inputs(dims, window, 23, true);
        let spec = CorrSpec::new(window, groups);
        let out_shape = [n, groups * x.k, h, w];
        let wts = inputs(out_shape, window, 29, false).left;
        let shapes = [dims, dims, [n, 2, h, w], [n, 2 * x.k, h, w]];
        let base = [&x.left, &x.right, &x.flow, &x.offset];
        let loss = |vals: &[Vec<f32>; 4]| -> f64 {
            let out = agcl::offset_corr(
                t4::<B>(&vals[0], shapes[0]),
                t4::<B>(&vals[1], shapes[1]),
                t4::<B>(&vals[2], shapes[2]),
                t4::<B>(&vals[3], shapes[3]),
                spec,
            );
            values(out)
                .iter()
                .zip(&wts)
                .map(|(a, b)| *a as f64 * *b as f64)
                .sum()
        };
        let analytic = agcl::offset_corr_backward(
            t4::<B>(base[0], shapes[0]),
            t4::<B>(base[1], shapes[1]),
            t4::<B>(base[2], shapes[2]),
            t4::<B>(base[3], shapes[3]),
            t4::<B>(&wts, out_shape),
            spec,
        )
        .expect("a backend with AGCL kernels")
        .map(values);
        for (which, name) in ["left", "right", "flow", "offset"].iter().enumerate() {
            // direction: random ±1 entries; features step 1e-2, coordinates 1e-2 px
            let dir: Vec<f32> = inputs(shapes[which], window, 31 + which as u64, false)
                .left
                .iter()
                .map(|v| if *v >= 0.0 { 1.0 } else { -1.0 })
                .collect();
            let eps = 1e-2f32;
            let shifted = |sign: f32| -> [Vec<f32>; 4] {
                let mut vals = base.map(|v| v.clone());
                for (v, d) in vals[which].iter_mut().zip(&dir) {
                    *v += sign * eps * d;
                }
                vals
            };
            let fd = (loss(&shifted(1.0)) - loss(&shifted(-1.0))) / (2.0 * eps as f64);
            let an: f64 = analytic[which]
                .iter()
                .zip(&dir)
                .map(|(g, d)| *g as f64 * *d as f64)
                .sum();
            let rel = (fd - an).abs() / an.abs().max(1e-3);
            println!(
                "{window:?} d/d{name}: analytic {an:.6e}, finite difference {fd:.6e}, rel {rel:.2e}"
            );
            assert!(
                rel <= 2e-3,
                "{window:?} d/d{name}: analytic {an} vs FD {fd}"
            );
        }
    }
}
