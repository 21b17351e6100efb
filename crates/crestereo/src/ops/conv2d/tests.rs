//! The convolution paths against Burn's own convolution, forward and every gradient.

use burn::module::AutodiffModule;
use burn::nn::PaddingConfig2d;
use burn::tensor::Distribution;

use super::*;

type Ad = Autodiff<Flex>;

fn values<B: Backend>(t: Tensor<B, 4>) -> Vec<f32> {
    t.into_data().convert::<f32>().into_vec().unwrap() // host read: unit test only
}

/// Tolerance for a gradient `reference`: 1e-4, or 1e-5 of its largest magnitude where that is
/// larger (a weight gradient sums hundreds of products of unit-size values: float32 summation
/// in another order differs by more than 1e-4 there).
fn grad_tolerance(reference: &[f32]) -> f32 {
    let scale = reference.iter().fold(0f32, |m, v| m.max(v.abs()));
    (1e-5 * scale).max(1e-4)
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// The GEMM path against Burn's own convolution, forward and both gradients, including maps
/// smaller than the kernel's reach (a tap that only ever reads padding) and strides.
#[test]
fn gemm_convolution_matches_burn_forward_and_gradients() {
    // (cin, cout, kernel, stride, padding, dilation, h, w)
    let cases = [
        (3, 4, 3, 1, 1, 1, 5, 7),
        (2, 3, 7, 2, 3, 1, 2, 2),
        (4, 2, 3, 1, 1, 1, 1, 3),
        (2, 2, 1, 1, 0, 1, 3, 4),
        (3, 2, 3, 2, 1, 1, 6, 5),
        (2, 3, 3, 1, 2, 2, 4, 4),
        // stride 1 with 16+ input channels: the shifted-view path
        (16, 5, 3, 1, 1, 1, 5, 7),
        (17, 3, 3, 1, 2, 2, 4, 6),
        (16, 4, 5, 1, 2, 1, 2, 3),
        (20, 6, 3, 1, 0, 1, 4, 5),
    ];
    for case in cases {
        compare_with_burn(case);
    }
}

/// Stride-1 3×3, 1×5 and 5×1 convolutions with 16+ channels on both sides and 256+
/// outputs: the Winograd path (forward, and the input gradient as the forward of the flipped
/// kernel), paddings from 0 to k − 1, odd sizes (tiles reaching past the map).
#[test]
fn winograd_convolution_matches_burn_forward_and_gradients() {
    // (cin, cout, kernel, padding, h, w)
    let cases = [
        (16, 16, [3, 3], [1, 1], 16, 17),
        (16, 20, [3, 3], [0, 0], 18, 19),
        (24, 16, [3, 3], [2, 2], 16, 17),
        (32, 48, [3, 3], [1, 1], 16, 16),
        (24, 16, [1, 5], [0, 2], 16, 19),
        (16, 24, [5, 1], [2, 0], 21, 16),
        (16, 16, [1, 5], [0, 4], 16, 16),
        (20, 16, [5, 1], [1, 0], 23, 17),
    ];
    for (cin, cout, [kh, kw], [ph, pw], h, w) in cases {
        let case = format!("cin {cin} cout {cout} {kh}x{kw} pad {ph},{pw} {h}x{w}");
        let x = FlexTensor::from_data(TensorData::new(vec![0f32; 2 * cin * h * w], [2, cin, h, w]));
        let wt = FlexTensor::from_data(TensorData::new(
            vec![0f32; cout * cin * kh * kw],
            [cout, cin, kh, kw],
        ));
        let g = Geometry::new(&x, &wt, &ConvOptions::new([1, 1], [ph, pw], [1, 1], 1));
        assert!(
            winograd::applies(&g) && winograd::applies_to_input_grad(&g),
            "{case} does not exercise the Winograd path"
        );
        compare_with_burn_kernel(cin, cout, [kh, kw], [1, 1], [ph, pw], [1, 1], h, w);
    }
}

/// Maps large enough for several Winograd blocks per image (the cases above fit in one): the
/// forward's 64-tile blocks and the weight gradient's sums over blocks. On one worker thread
/// one partial dU accumulates every block; on four, a 48×64 map's 768 F(2, 3) tiles, three
/// blocks of 256 per image, become four of 192 (`balanced_block`) summed in several parts.
#[test]
fn winograd_convolution_over_several_blocks_matches_burn() {
    for threads in [1, 4] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool");
        pool.install(|| {
            compare_with_burn_kernel(16, 16, [3, 3], [1, 1], [1, 1], [1, 1], 48, 64);
            compare_with_burn_kernel(16, 24, [1, 5], [1, 1], [0, 2], [1, 1], 48, 64);
        });
    }
}

/// One square-kernel convolution (cin, cout, kernel, stride, padding, dilation, h, w): see
/// [`compare_with_burn_kernel`].
fn compare_with_burn(
    (cin, cout, k, s, p, d, h, w): (usize, usize, usize, usize, usize, usize, usize, usize),
) {
    compare_with_burn_kernel(cin, cout, [k, k], [s, s], [p, p], [d, d], h, w);
}

/// One convolution on a batch of two: ours against Burn's, forward and the gradients of
/// input, weight and bias on `Autodiff<Flex>`, and the plain Flex forward.
#[allow(clippy::too_many_arguments)]
fn compare_with_burn_kernel(
    cin: usize,
    cout: usize,
    kernel: [usize; 2],
    stride: [usize; 2],
    [ph, pw]: [usize; 2],
    dilation: [usize; 2],
    h: usize,
    w: usize,
) {
    let device = Default::default();
    let conv = Conv2dConfig::new([cin, cout], kernel)
        .with_stride(stride)
        .with_dilation(dilation)
        .with_padding(PaddingConfig2d::Explicit(ph, pw, ph, pw))
        .init::<Ad>(&device);
    let x = Tensor::<Ad, 4>::random([2, cin, h, w], Distribution::Normal(0.0, 1.0), &device)
        .require_grad();
    let ours = conv.forward(x.clone());
    let theirs = composed::conv2d(&conv, x.clone());
    let case = format!(
        "cin {cin} cout {cout} kernel {kernel:?} stride {stride:?} pad {ph},{pw} \
         dilation {dilation:?} {h}x{w}"
    );
    assert_eq!(ours.dims(), theirs.dims(), "{case}");
    let fwd = max_diff(&values(ours.clone()), &values(theirs.clone()));
    assert!(fwd <= 1e-5, "{case}: forward differs by {fwd}");
    let up = Tensor::<Ad, 4>::random(ours.dims(), Distribution::Normal(0.0, 1.0), &device);
    let g_ours = (ours * up.clone()).sum().backward();
    let g_theirs = (theirs * up).sum().backward();
    let pairs = [
        (x.grad(&g_ours).unwrap(), x.grad(&g_theirs).unwrap(), "dx"),
        (
            conv.weight.val().grad(&g_ours).unwrap(),
            conv.weight.val().grad(&g_theirs).unwrap(),
            "dw",
        ),
    ];
    for (a, b, name) in pairs {
        let (a, b) = (values(a), values(b));
        let (diff, tol) = (max_diff(&a, &b), grad_tolerance(&b));
        assert!(
            diff <= tol,
            "{case}: {name} differs by {diff} (tolerance {tol})"
        );
    }
    // the bias is added inside the convolution: its gradient comes from our backward
    let bias = conv.bias.as_ref().expect("a bias").val();
    let as4 = |t: Tensor<Flex, 1>| values(t.reshape([1, 1, 1, cout]));
    let (a, b) = (
        as4(bias.grad(&g_ours).unwrap()),
        as4(bias.grad(&g_theirs).unwrap()),
    );
    let (db, tol) = (max_diff(&a, &b), grad_tolerance(&b));
    assert!(db <= tol, "{case}: db differs by {db} (tolerance {tol})");
    // the plain Flex forward takes the GEMM path too
    let xf = x.inner();
    let conv_f = conv.valid();
    let diff = max_diff(
        &values(conv_f.forward(xf.clone())),
        &values(composed::conv2d(&conv_f, xf)),
    );
    assert!(diff <= 1e-5, "{case}: Flex forward differs by {diff}");
}

/// The GRU's separable kernels (1×5 and 5×1, 16+ channels: the shifted-view path) against
/// Burn's convolution, forward and both gradients, also on maps narrower than the kernel.
#[test]
fn separable_kernels_match_burn_forward_and_gradients() {
    let device = Default::default();
    // (kernel, padding, h, w)
    let cases = [
        ([1, 5], [0, 2], 4, 6),
        ([5, 1], [2, 0], 6, 3),
        ([1, 5], [0, 2], 3, 2),
        ([5, 1], [2, 0], 1, 4),
    ];
    for (kernel, [ph, pw], h, w) in cases {
        let conv = Conv2dConfig::new([16, 3], kernel)
            .with_padding(PaddingConfig2d::Explicit(ph, pw, ph, pw))
            .init::<Ad>(&device);
        let x = Tensor::<Ad, 4>::random([2, 16, h, w], Distribution::Normal(0.0, 1.0), &device)
            .require_grad();
        let (ours, theirs) = (conv.forward(x.clone()), composed::conv2d(&conv, x.clone()));
        let case = format!("kernel {kernel:?} on {h}x{w}");
        let fwd = max_diff(&values(ours.clone()), &values(theirs.clone()));
        assert!(fwd <= 1e-5, "{case}: forward differs by {fwd}");
        let up = Tensor::<Ad, 4>::random(ours.dims(), Distribution::Normal(0.0, 1.0), &device);
        let g_ours = (ours * up.clone()).sum().backward();
        let g_theirs = (theirs * up).sum().backward();
        for (a, b, name) in [
            (x.grad(&g_ours).unwrap(), x.grad(&g_theirs).unwrap(), "dx"),
            (
                conv.weight.val().grad(&g_ours).unwrap(),
                conv.weight.val().grad(&g_theirs).unwrap(),
                "dw",
            ),
        ] {
            let diff = max_diff(&values(a), &values(b));
            assert!(diff <= 1e-4, "{case}: {name} differs by {diff}");
        }
    }
}

/// Stacked convolutions (a GRU's z and r gates) against the convolutions one by one: the
/// outputs and the gradients of the input, both weights and both biases.
#[test]
fn stacked_convolutions_match_separate_ones() {
    let device = Default::default();
    let make = || {
        Conv2dConfig::new([16, 4], [1, 5])
            .with_padding(PaddingConfig2d::Explicit(0, 2, 0, 2))
            .init::<Ad>(&device)
    };
    let (a, b) = (make(), make());
    let x = Tensor::<Ad, 4>::random([2, 16, 5, 7], Distribution::Normal(0.0, 1.0), &device)
        .require_grad();
    let stacked = forward_stacked(&[&a, &b], x.clone());
    let separate = crate::ops::channels::cat(
        vec![
            composed::conv2d(&a, x.clone()),
            composed::conv2d(&b, x.clone()),
        ],
        1,
    );
    assert_eq!(stacked.dims(), [2, 8, 5, 7]);
    let fwd = max_diff(&values(stacked.clone()), &values(separate.clone()));
    assert!(fwd <= 1e-5, "forward differs by {fwd}");
    let up = Tensor::<Ad, 4>::random([2, 8, 5, 7], Distribution::Normal(0.0, 1.0), &device);
    let g1 = (stacked * up.clone()).sum().backward();
    let g2 = (separate * up).sum().backward();
    let grad4 = |t: Tensor<Ad, 4>| (values(t.grad(&g1).unwrap()), values(t.grad(&g2).unwrap()));
    for (name, (p, q)) in [
        ("dx", grad4(x.clone())),
        ("dw a", grad4(a.weight.val())),
        ("dw b", grad4(b.weight.val())),
    ] {
        let diff = max_diff(&p, &q);
        assert!(diff <= 1e-4, "{name} differs by {diff}");
    }
    for (name, conv) in [("db a", &a), ("db b", &b)] {
        let bias = conv.bias.as_ref().unwrap().val();
        let as4 = |t: Tensor<Flex, 1>| values(t.reshape([1, 1, 1, 4]));
        let diff = max_diff(&as4(bias.grad(&g1).unwrap()), &as4(bias.grad(&g2).unwrap()));
        assert!(diff <= 1e-4, "{name} differs by {diff}");
    }
}

/// The matrix-product composition (the CubeCL path) against Burn's convolution: forward and the
/// gradients of input, weight and bias, with paddings, dilation, separable kernels and the
/// encoder's strided convolutions (7×7/2, 3×3/2, 1×1/2, odd and even sizes).
#[test]
fn matmul_composition_matches_burn_forward_and_gradients() {
    // (cin, cout, kernel, padding, dilation, stride, h, w)
    let cases = [
        (3, 4, [3, 3], [1, 1], [1, 1], 1, 5, 7),
        (4, 2, [1, 1], [0, 0], [1, 1], 1, 3, 4),
        (5, 3, [1, 5], [0, 2], [1, 1], 1, 4, 6),
        (5, 3, [5, 1], [2, 0], [1, 1], 1, 6, 4),
        (2, 3, [3, 3], [2, 2], [2, 2], 1, 4, 5),
        (2, 2, [7, 7], [3, 3], [1, 1], 1, 3, 3),
        (3, 4, [7, 7], [3, 3], [1, 1], 2, 9, 12),
        (4, 3, [3, 3], [1, 1], [1, 1], 2, 8, 7),
        (4, 3, [1, 1], [0, 0], [1, 1], 2, 6, 5),
    ];
    let device = Default::default();
    for (cin, cout, kernel, [ph, pw], dilation, stride, h, w) in cases {
        let conv = Conv2dConfig::new([cin, cout], kernel)
            .with_stride([stride, stride])
            .with_dilation(dilation)
            .with_padding(PaddingConfig2d::Explicit(ph, pw, ph, pw))
            .init::<Ad>(&device);
        let x = Tensor::<Ad, 4>::random([2, cin, h, w], Distribution::Normal(0.0, 1.0), &device)
            .require_grad();
        let case = format!(
            "cin {cin} cout {cout} kernel {kernel:?} pad {ph},{pw} dil {dilation:?} stride {stride}"
        );
        let (ours, theirs) = (
            conv.forward_by_matmul(x.clone()),
            composed::conv2d(&conv, x.clone()),
        );
        assert_eq!(ours.dims(), theirs.dims(), "{case}");
        let fwd = max_diff(&values(ours.clone()), &values(theirs.clone()));
        assert!(fwd <= 1e-5, "{case}: forward differs by {fwd}");
        let up = Tensor::<Ad, 4>::random(ours.dims(), Distribution::Normal(0.0, 1.0), &device);
        let g1 = (ours * up.clone()).sum().backward();
        let g2 = (theirs * up).sum().backward();
        for (name, t) in [("dx", x.clone()), ("dw", conv.weight.val())] {
            let (a, b) = (values(t.grad(&g1).unwrap()), values(t.grad(&g2).unwrap()));
            let diff = max_diff(&a, &b);
            assert!(
                diff <= grad_tolerance(&b),
                "{case}: {name} differs by {diff}"
            );
        }
        let bias = conv.bias.as_ref().unwrap().val();
        let as4 = |t: Tensor<Flex, 1>| values(t.reshape([1, 1, 1, cout]));
        let (a, b) = (as4(bias.grad(&g1).unwrap()), as4(bias.grad(&g2).unwrap()));
        assert!(max_diff(&a, &b) <= grad_tolerance(&b), "{case}: db differs");
    }
}

/// Each convolution geometry of the network as a graph `Conv` node (Burn's convolution in the
/// evaluator) against `Conv2d::forward` on Flex (the GEMM, Winograd and shifted-view kernels).
#[test]
fn emitted_convolutions_match_forward() {
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    let device = Default::default();
    // (in, out, kernel, stride, padding): the encoder's 7×7/2 and 3×3/2, the 3×3, 1×1, 1×5 and
    // 5×1 of the blocks and the GRU, the 7×7 of the motion encoder.
    let geometries = [
        (3, 8, [7, 7], 2, [3, 3]),
        (8, 16, [3, 3], 2, [1, 1]),
        (16, 16, [3, 3], 1, [1, 1]),
        (16, 12, [1, 1], 1, [0, 0]),
        (24, 16, [1, 5], 1, [0, 2]),
        (24, 16, [5, 1], 1, [2, 0]),
        (2, 16, [7, 7], 1, [3, 3]),
    ];
    for (cin, cout, kernel, stride, [ph, pw]) in geometries {
        let conv = Conv2dConfig::new([cin, cout], kernel)
            .with_stride([stride; 2])
            .with_padding(PaddingConfig2d::Explicit(ph, pw, ph, pw))
            .init::<Flex>(&device);
        let x =
            Tensor::<Flex, 4>::random([2, cin, 13, 18], Distribution::Uniform(-1.0, 1.0), &device);
        let out = run_emitted(&[x.to_data()], |g, v| vec![conv.emit(g, &v[0])]);
        let label = format!("{cin}->{cout} {kernel:?}/{stride}");
        assert_emit_matches(&label, &out[0], conv.forward(x).into_data(), 1e-5);
    }
}
