//! 2-D convolution with a GEMM backward on the CPU training backend.
//!
//! Burn's Flex backend differentiates a convolution through its generic fallbacks: the weight
//! gradient as a convolution whose kernel is the whole output-gradient map (one skinny matrix
//! product per input channel) and the input gradient as a scatter-based transposed
//! convolution. Here, on `Autodiff<Flex>`, the backward is the textbook pair of matrix products
//! over the unfolded input (`im2col`, built per row of the unfolded matrix, in parallel):
//!
//! * `dW = dY · colsᵀ` (C_out × N·P times N·P × C_in·kh·kw),
//! * `dX = col2im(Wᵀ · dY)`, scattered back per input channel (no two tasks write one plane).
//!
//! The forward (on `Flex` too) is one matrix product per image, `Y_b = W · cols_b`, written
//! in NCHW directly. Stride-1 convolutions with enough input channels skip the unfolding
//! altogether: 3×3, 1×5 and 5×1 kernels by Winograd's minimal filtering (`winograd`; larger
//! tiles on `Flex`, i.e. inference, than on `Autodiff<Flex>`), others as a sum of products over
//! shifted views of the padded input (`shifted`). Every other backend, float64 tensors and
//! grouped convolutions run Burn's convolution ([`composed::conv2d`]); the model's
//! convolutions are [`Conv2d`] modules, whose `forward` makes that choice.

use burn::backend::autodiff::NodeId;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::module::{Param, ParamId};
use burn::prelude::*;
use burn::tensor::ops::{ConvOptions, FloatTensor};
use burn::tensor::{TensorData, TensorMetadata, TensorPrimitive};
use rayon::prelude::*;

use crate::ops::dispatch::{Kernels, same};
use views::{Threads, View, matmul_into};

mod by_matmul;
pub mod composed;
mod module;
mod scratch;
mod shifted;
mod views;
mod winograd;

pub use module::{Conv2d, Conv2dConfig};
use winograd::Use;

/// Whether the Flex kernels take `conv`: groups 1 and a symmetric padding.
pub(crate) fn kernels_apply<B: Backend>(conv: &Conv2d<B>) -> bool {
    conv.groups == 1 && conv.symmetric_padding().is_some()
}

/// The Flex kernels' convolution of float32 `x` (`choice` a Flex family, [`kernels_apply`]
/// true).
pub(crate) fn kernel_forward<B: Backend>(
    conv: &Conv2d<B>,
    x: Tensor<B, 4>,
    choice: Kernels,
) -> Tensor<B, 4> {
    let padding = conv.symmetric_padding().expect("kernels_apply");
    let options = ConvOptions::new(conv.stride, padding, conv.dilation, 1);
    let (x, w) = (
        x.into_primitive().tensor(),
        conv.weight.val().into_primitive().tensor(),
    );
    let bias = (conv.bias.as_ref()).map(|b| b.val().into_primitive().tensor());
    let y = if choice == Kernels::AutodiffFlex {
        same(conv2d_autodiff(same(x), same(w), bias.map(same), options))
    } else {
        let (x, w): (FlexTensor, FlexTensor) = (same(x), same(w));
        let y = gemm_forward(&x, &w, &Geometry::new(&x, &w, &options), Use::Inference);
        same(match bias {
            Some(b) => add_bias(y, &same(b)),
            None => y,
        })
    };
    Tensor::from_primitive(TensorPrimitive::Float(y))
}

/// Several convolutions of one input with the same geometry (kernel, stride, padding, dilation),
/// as one: their outputs concatenated along channels, in order. On the GEMM path this is one
/// matrix product over one unfolded input (a GRU's update and reset gates read the same input),
/// instead of one unfolding and one product per convolution; elsewhere it is the convolutions
/// one by one. Same numbers either way up to float32 summation order.
pub fn forward_stacked<B: Backend>(convs: &[&Conv2d<B>], x: Tensor<B, 4>) -> Tensor<B, 4> {
    let first = convs[0];
    let same_geometry = convs.iter().all(|c| {
        c.weight.dims()[1..] == first.weight.dims()[1..]
            && c.stride == first.stride
            && c.dilation == first.dilation
            && c.groups == first.groups
            && c.padding == first.padding
            && c.bias.is_some() == first.bias.is_some()
    });
    if convs.len() == 1 || !same_geometry {
        return crate::ops::channels::cat(convs.iter().map(|c| c.forward(x.clone())).collect(), 1);
    }
    let stacked = Conv2d {
        // `Param::initialized`, not `from_tensor`: the stacked tensors stay in the autodiff graph
        // of the parameters they are made of (from_tensor would mark them as new leaves).
        weight: Param::initialized(
            ParamId::new(),
            crate::ops::channels::cat(convs.iter().map(|c| c.weight.val()).collect(), 0),
        ),
        bias: first.bias.as_ref().map(|_| {
            Param::initialized(
                ParamId::new(),
                crate::ops::channels::cat(
                    convs
                        .iter()
                        .map(|c| c.bias.as_ref().expect("checked above").val())
                        .collect(),
                    0,
                ),
            )
        }),
        stride: first.stride,
        kernel_size: first.kernel_size,
        dilation: first.dilation,
        groups: first.groups,
        padding: first.padding.clone(),
    };
    stacked.forward(x)
}

#[derive(Debug)]
struct Conv2dBackward;

impl Backward<Flex, 2> for Conv2dBackward {
    type State = (FlexTensor, FlexTensor, ConvOptions<2>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_w] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node).to_contiguous();
        register_grads(
            grads,
            [node_x, node_w].map(|n| n.map(|n| n.id)),
            &dy,
            ops.state,
        );
    }
}

/// A convolution with its bias added in the same pass (no broadcast add after it).
#[derive(Debug)]
struct Conv2dBiasBackward;

impl Backward<Flex, 3> for Conv2dBiasBackward {
    type State = (FlexTensor, FlexTensor, ConvOptions<2>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_w, node_b] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node).to_contiguous();
        if let Some(node) = node_b {
            grads.register::<Flex>(node.id, bias_grad(&dy));
        }
        register_grads(
            grads,
            [node_x, node_w].map(|n| n.map(|n| n.id)),
            &dy,
            ops.state,
        );
    }
}

/// Registers the input and weight gradients of a convolution for the parents that need them.
fn register_grads(
    grads: &mut Gradients,
    [node_x, node_w]: [Option<NodeId>; 2],
    dy: &FlexTensor,
    (x, w, options): (FlexTensor, FlexTensor, ConvOptions<2>),
) {
    let geometry = Geometry::new(&x, &w, &options);
    if let Some(id) = node_w {
        grads.register::<Flex>(id, weight_grad(&x, dy, &geometry));
    }
    if let Some(id) = node_x {
        grads.register::<Flex>(id, input_grad(&w, dy, &geometry));
    }
}

/// `y + bias` per output channel, in place (y is the convolution's fresh output), in parallel
/// over planes: Flex's broadcast add would walk every element through a strided iterator on
/// one thread.
fn add_bias(y: FlexTensor, bias: &FlexTensor) -> FlexTensor {
    // `to_contiguous` of a contiguous map shares its buffer; with `y` still held, `storage_mut`
    // would copy the whole map (on the calling thread alone) before writing into it.
    let mut y = {
        let contiguous = y.to_contiguous();
        drop(y);
        contiguous
    };
    let [_, c, h, w] = y.shape().dims();
    let bias = bias.to_contiguous();
    let b: &[f32] = bias.storage();
    y.storage_mut::<f32>()
        .par_chunks_mut(h * w)
        .enumerate()
        .for_each(|(i, plane)| {
            let v = b[i % c];
            plane.iter_mut().for_each(|x| *x += v);
        });
    y
}

/// `dB` (C) = the output gradient summed over images and pixels.
fn bias_grad(dy: &FlexTensor) -> FlexTensor {
    let [n, c, h, w] = dy.shape().dims();
    let g: &[f32] = dy.storage();
    let db: Vec<f32> = (0..c)
        .into_par_iter()
        .map(|k| {
            (0..n)
                .map(|b| g[(b * c + k) * h * w..][..h * w].iter().sum::<f32>())
                .sum()
        })
        .collect();
    FlexTensor::from_data(TensorData::new(db, [c]))
}

fn conv2d_autodiff(
    x: FloatTensor<Autodiff<Flex>>,
    w: FloatTensor<Autodiff<Flex>>,
    bias: Option<FloatTensor<Autodiff<Flex>>>,
    options: ConvOptions<2>,
) -> FloatTensor<Autodiff<Flex>> {
    let forward = |x: &FlexTensor, w: &FlexTensor, b: Option<&FlexTensor>| {
        let y = gemm_forward(x, w, &Geometry::new(x, w, &options), Use::Training);
        match b {
            Some(b) => add_bias(y, b),
            None => y,
        }
    };
    let Some(bias) = bias else {
        let nodes = [x.node.clone(), w.node.clone()];
        let (x, w) = (x.primitive, w.primitive);
        return match Conv2dBackward
            .prepare::<NoCheckpointing>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let y = forward(&x, &w, None);
                prep.finish((x, w, options), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward(&x, &w, None)),
        };
    };
    let nodes = [x.node.clone(), w.node.clone(), bias.node.clone()];
    let (x, w, b) = (x.primitive, w.primitive, bias.primitive);
    match Conv2dBiasBackward
        .prepare::<NoCheckpointing>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let y = forward(&x, &w, Some(&b));
            prep.finish((x, w, options), y)
        }
        OpsKind::UnTracked(prep) => prep.finish(forward(&x, &w, Some(&b))),
    }
}

/// Sizes of one convolution.
#[derive(Clone, Copy, Debug)]
struct Geometry {
    n: usize,
    cin: usize,
    h: usize,
    w: usize,
    cout: usize,
    kh: usize,
    kw: usize,
    ho: usize,
    wo: usize,
    stride: [usize; 2],
    pad: [usize; 2],
    dil: [usize; 2],
}

impl Geometry {
    fn new(x: &FlexTensor, w: &FlexTensor, o: &ConvOptions<2>) -> Self {
        let [n, cin, h, wd] = x.shape().dims();
        let [cout, _, kh, kw] = w.shape().dims();
        let out = |i: usize, k: usize, d: usize| {
            (i + 2 * o.padding[d] - o.dilation[d] * (k - 1) - 1) / o.stride[d] + 1
        };
        Geometry {
            n,
            cin,
            h,
            w: wd,
            cout,
            kh,
            kw,
            ho: out(h, kh, 0),
            wo: out(wd, kw, 1),
            stride: o.stride,
            pad: o.padding,
            dil: o.dilation,
        }
    }

    fn k(&self) -> usize {
        self.cin * self.kh * self.kw
    }

    fn p(&self) -> usize {
        self.ho * self.wo
    }

    /// Input coordinate of output coordinate `o` for kernel tap `t` along axis `d`.
    #[inline]
    fn src(&self, o: usize, t: usize, d: usize) -> isize {
        (o * self.stride[d] + t * self.dil[d]) as isize - self.pad[d] as isize
    }

    /// Output range along axis `d` whose input coordinate for tap `t` lies in `0..len`.
    fn valid(&self, t: usize, d: usize, len: usize, out_len: usize) -> std::ops::Range<usize> {
        let lo = (0..out_len)
            .find(|&o| self.src(o, t, d) >= 0)
            .unwrap_or(out_len);
        let hi = (lo..out_len)
            .find(|&o| self.src(o, t, d) >= len as isize)
            .unwrap_or(out_len);
        lo..hi
    }
}

/// Unfolded input of image `b`: (C_in·kh·kw, P), row `(ci, a, c)` = the input plane `ci`
/// sampled at tap (a, c) for every output pixel (zero in the padding).
fn im2col(x: &[f32], g: &Geometry, b: usize) -> Vec<f32> {
    let p = g.p();
    let mut cols = vec![0f32; g.k() * p];
    cols.par_chunks_mut(p).enumerate().for_each(|(row, dst)| {
        let (ci, a, c) = (row / (g.kh * g.kw), (row / g.kw) % g.kh, row % g.kw);
        let plane = &x[(b * g.cin + ci) * g.h * g.w..(b * g.cin + ci + 1) * g.h * g.w];
        let xs = g.valid(c, 1, g.w, g.wo);
        if xs.is_empty() {
            // This tap reads only padding along x (small maps): the row stays zero, and the
            // source offset of an empty range may be negative.
            return;
        }
        for oy in g.valid(a, 0, g.h, g.ho) {
            let iy = g.src(oy, a, 0) as usize;
            let out_row = &mut dst[oy * g.wo..(oy + 1) * g.wo];
            if g.stride[1] == 1 && g.dil[1] == 1 {
                let ix0 = g.src(xs.start, c, 1) as usize;
                out_row[xs.clone()]
                    .copy_from_slice(&plane[iy * g.w + ix0..iy * g.w + ix0 + xs.len()]);
            } else {
                for ox in xs.clone() {
                    out_row[ox] = plane[iy * g.w + g.src(ox, c, 1) as usize];
                }
            }
        }
    });
    cols
}

/// Adds the unfolded gradient `cols` (C_in·kh·kw, P) of image `b` back onto its input planes.
fn col2im(cols: &[f32], dx: &mut [f32], g: &Geometry, b: usize) {
    let p = g.p();
    let taps = g.kh * g.kw;
    dx[b * g.cin * g.h * g.w..(b + 1) * g.cin * g.h * g.w]
        .par_chunks_mut(g.h * g.w)
        .enumerate()
        .for_each(|(ci, plane)| {
            for t in 0..taps {
                let (a, c) = (t / g.kw, t % g.kw);
                let src = &cols[(ci * taps + t) * p..(ci * taps + t + 1) * p];
                let xs = g.valid(c, 1, g.w, g.wo);
                for oy in g.valid(a, 0, g.h, g.ho) {
                    let iy = g.src(oy, a, 0) as usize;
                    for ox in xs.clone() {
                        plane[iy * g.w + g.src(ox, c, 1) as usize] += src[oy * g.wo + ox];
                    }
                }
            }
        });
}

/// `Y_b = W · cols_b` for every image b, (N, C_out, H_out, W_out), NCHW without a layout
/// change (1×1 stride-1 convolutions multiply the input planes directly). `use_` picks the
/// Winograd tiles: larger for inference, smaller (more accurate) in training.
fn gemm_forward(x: &FlexTensor, w: &FlexTensor, g: &Geometry, use_: Use) -> FlexTensor {
    let x = x.to_contiguous();
    if winograd::applies(g) {
        let y = winograd::forward(x.storage(), w.to_contiguous().storage(), g, use_);
        return FlexTensor::from_data(TensorData::new(y, [g.n, g.cout, g.ho, g.wo]));
    }
    if shifted::applies(g) {
        let y = shifted::forward(x.storage(), w.to_contiguous().storage(), g);
        return FlexTensor::from_data(TensorData::new(y, [g.n, g.cout, g.ho, g.wo]));
    }
    // The general path (strided, 1×1, few channels): one product per image on slices, split
    // over the threads from a much smaller size than Flex's own matmul would split it.
    let (p, k) = (g.p(), g.k());
    let w = w.to_contiguous();
    let (x, w): (&[f32], &[f32]) = (x.storage(), w.storage());
    let pointwise = g.kh == 1 && g.kw == 1 && g.stride == [1, 1] && g.pad == [0, 0];
    let mut y = vec![0f32; g.n * g.cout * p];
    for (b, y_b) in y.chunks_exact_mut(g.cout * p).enumerate() {
        let unfolded;
        let cols: &[f32] = if pointwise {
            &x[b * k * p..][..k * p]
        } else {
            unfolded = im2col(x, g, b);
            &unfolded
        };
        let (d, l, r) = (View::new(0, p, 1), View::new(0, k, 1), View::new(0, p, 1));
        matmul_into(Threads::Pool, (g.cout, p, k), y_b, d, false, w, l, cols, r);
    }
    FlexTensor::from_data(TensorData::new(y, [g.n, g.cout, g.ho, g.wo]))
}

/// `dW = Σ_b dY_b · cols_bᵀ`, (C_out, C_in, kh, kw).
fn weight_grad(x: &FlexTensor, dy: &FlexTensor, g: &Geometry) -> FlexTensor {
    let x = x.to_contiguous();
    if winograd::applies(g) {
        let dw = winograd::weight_grad(x.storage(), dy.to_contiguous().storage(), g);
        return FlexTensor::from_data(TensorData::new(dw, [g.cout, g.cin, g.kh, g.kw]));
    }
    if shifted::applies(g) {
        let dw = shifted::weight_grad(x.storage(), dy.to_contiguous().storage(), g);
        return FlexTensor::from_data(TensorData::new(dw, [g.cout, g.cin, g.kh, g.kw]));
    }
    let (p, k) = (g.p(), g.k());
    let dy = dy.to_contiguous();
    let (xs, dys): (&[f32], &[f32]) = (x.storage(), dy.storage());
    let mut dw = vec![0f32; g.cout * k];
    for b in 0..g.n {
        let cols = im2col(xs, g, b);
        // dW (cout × k) += dY_b (cout × p) · cols_bᵀ (p × k)
        let (d, l, r) = (
            View::new(0, k, 1),
            View::new(b * g.cout * p, p, 1),
            View::new(0, 1, p),
        );
        matmul_into(
            Threads::Pool,
            (g.cout, k, p),
            &mut dw,
            d,
            b > 0,
            dys,
            l,
            &cols,
            r,
        );
    }
    FlexTensor::from_data(TensorData::new(dw, [g.cout, g.cin, g.kh, g.kw]))
}

/// `dX = col2im(Wᵀ · dY_b)` for every image b, (N, C_in, H, W).
fn input_grad(w: &FlexTensor, dy: &FlexTensor, g: &Geometry) -> FlexTensor {
    if winograd::applies_to_input_grad(g) {
        let dx = winograd::input_grad(w.to_contiguous().storage(), dy.to_contiguous().storage(), g);
        return FlexTensor::from_data(TensorData::new(dx, [g.n, g.cin, g.h, g.w]));
    }
    if shifted::applies(g) {
        let dx = shifted::input_grad(w.to_contiguous().storage(), dy.to_contiguous().storage(), g);
        return FlexTensor::from_data(TensorData::new(dx, [g.n, g.cin, g.h, g.w]));
    }
    let (p, k) = (g.p(), g.k());
    let (w, dy) = (w.to_contiguous(), dy.to_contiguous());
    let (ws, dys): (&[f32], &[f32]) = (w.storage(), dy.storage());
    let mut dx = vec![0f32; g.n * g.cin * g.h * g.w];
    let mut cols = vec![0f32; k * p];
    for b in 0..g.n {
        // cols (k × p) = Wᵀ (k × cout) · dY_b (cout × p)
        let (d, l, r) = (
            View::new(0, p, 1),
            View::new(0, 1, k),
            View::new(b * g.cout * p, p, 1),
        );
        matmul_into(
            Threads::Pool,
            (k, p, g.cout),
            &mut cols,
            d,
            false,
            ws,
            l,
            dys,
            r,
        );
        col2im(&cols, &mut dx, g, b);
    }
    FlexTensor::from_data(TensorData::new(dx, [g.n, g.cin, g.h, g.w]))
}

#[cfg(test)]
mod tests;
