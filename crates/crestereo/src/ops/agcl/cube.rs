//! [`AgclOps`] for CubeCL backends (every CubeCL runtime: CUDA with the `cuda` feature, wgpu
//! with `wgpu`/`vulkan`): `#[cube]` kernels for the forward and backward of both ops, and the
//! `Fusion<B>` wrapper that records each call as one custom operation of the fusion stream (no
//! flush, no host read).
//!
//! Threads: forward one per output element (x fastest, so loads and stores coalesce); the
//! offset-correlation backward one per pixel (it owns that pixel's left-map and offset
//! gradients); the right-map gradients are scatters and use float atomics.

use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl::{self, calculate_cube_count_elemwise, prelude::*};
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::{empty_device_contiguous_dtype, zeros_client};
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{BoolElement, CubeBackend, CubeRuntime, FloatElement, IntElement};

use super::{AgclOps, CorrSpec};

/// Bilinear corner value, zero outside the image.
#[cube]
fn corner(img: &Tensor<f32>, base: usize, xf: f32, yf: f32, width: usize, height: usize) -> f32 {
    let inside = xf >= 0.0
        && yf >= 0.0
        && xf <= f32::cast_from(width - 1)
        && yf <= f32::cast_from(height - 1);
    let xi = usize::cast_from(clamp(xf, 0.0, f32::cast_from(width - 1)));
    let yi = usize::cast_from(clamp(yf, 0.0, f32::cast_from(height - 1)));
    select(inside, img[base + yi * width + xi], 0.0)
}

#[cube]
fn is_inside(xf: f32, yf: f32, width: usize, height: usize) -> bool {
    xf >= 0.0 && yf >= 0.0 && xf <= f32::cast_from(width - 1) && yf <= f32::cast_from(height - 1)
}

#[cube]
fn corner_index(xf: f32, yf: f32, width: usize, height: usize) -> usize {
    let xi = usize::cast_from(clamp(xf, 0.0, f32::cast_from(width - 1)));
    let yi = usize::cast_from(clamp(yf, 0.0, f32::cast_from(height - 1)));
    yi * width + xi
}

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn offset_corr_kernel(
    left: &Tensor<f32>,
    right: &Tensor<f32>,
    flow: &Tensor<f32>,
    offset: &Tensor<f32>,
    output: &mut Tensor<f32>,
    units: usize,
    channels: usize,
    height: usize,
    width: usize,
    groups: usize,
    rx: usize,
    ry: usize,
) {
    if ABSOLUTE_POS < units {
        let hw = height * width;
        let row = 2 * rx + 1;
        let kn = row * (2 * ry + 1);
        let p = ABSOLUTE_POS % hw;
        let k = (ABSOLUTE_POS / hw) % kn;
        let n = ABSOLUTE_POS / (hw * kn);
        let x = p % width;
        let y = p / width;
        let fx = flow[(n * 2) * hw + p];
        let fy = flow[(n * 2 + 1) * hw + p];
        let ox = offset[(n * 2 * kn + 2 * k) * hw + p];
        let oy = offset[(n * 2 * kn + 2 * k + 1) * hw + p];
        let dx = f32::cast_from(k % row) - f32::cast_from(rx);
        let dy = f32::cast_from(k / row) - f32::cast_from(ry);
        let px = f32::cast_from(x) + fx + dx + ox;
        let py = f32::cast_from(y) + fy + dy + oy;
        let x0 = px.floor();
        let y0 = py.floor();
        let wx1 = px - x0;
        let wy1 = py - y0;
        let wx0 = 1.0 - wx1;
        let wy0 = 1.0 - wy1;
        let cg = channels / groups;
        for g in 0..groups {
            let mut acc = 0.0f32;
            for ci in 0..cg {
                let base = (n * channels + g * cg + ci) * hw;
                let s = wx0 * wy0 * corner(right, base, x0, y0, width, height)
                    + wx1 * wy0 * corner(right, base, x0 + 1.0, y0, width, height)
                    + wx0 * wy1 * corner(right, base, x0, y0 + 1.0, width, height)
                    + wx1 * wy1 * corner(right, base, x0 + 1.0, y0 + 1.0, width, height);
                acc += left[base + p] * s;
            }
            output[((n * groups + g) * kn + k) * hw + p] = acc / f32::cast_from(cg);
        }
    }
}

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn offset_corr_backward_kernel(
    left: &Tensor<f32>,
    right: &Tensor<f32>,
    flow: &Tensor<f32>,
    offset: &Tensor<f32>,
    grad: &Tensor<f32>,
    d_left: &mut Tensor<f32>,
    d_right: &mut Tensor<Atomic<f32>>,
    d_flow: &mut Tensor<f32>,
    d_offset: &mut Tensor<f32>,
    units: usize,
    channels: usize,
    height: usize,
    width: usize,
    groups: usize,
    rx: usize,
    ry: usize,
) {
    // No early return and no atomic under a branch that depends on the thread: threads past
    // `units` (the last cube's spare lanes) run the same code at the last pixel with their
    // contributions zeroed, and the scatters add `select(inside, v, 0)` at always-valid
    // indices. On lavapipe (Mesa 22.3) spare lanes that skipped the body around float atomics
    // corrupted the other outputs whenever the last cube was partial (found by the Vulkan tests).
    let valid = ABSOLUTE_POS < units;
    let pos = select(valid, ABSOLUTE_POS, units - 1);
    {
        let hw = height * width;
        let row = 2 * rx + 1;
        let kn = row * (2 * ry + 1);
        let p = pos % hw;
        let n = pos / hw;
        let x = p % width;
        let y = p / width;
        let fx = flow[(n * 2) * hw + p];
        let fy = flow[(n * 2 + 1) * hw + p];
        let cg = channels / groups;
        let mut dfx = 0.0f32;
        let mut dfy = 0.0f32;
        for k in 0..kn {
            let ox = offset[(n * 2 * kn + 2 * k) * hw + p];
            let oy = offset[(n * 2 * kn + 2 * k + 1) * hw + p];
            let dx = f32::cast_from(k % row) - f32::cast_from(rx);
            let dy = f32::cast_from(k / row) - f32::cast_from(ry);
            let px = f32::cast_from(x) + fx + dx + ox;
            let py = f32::cast_from(y) + fy + dy + oy;
            let x0 = px.floor();
            let y0 = py.floor();
            let wx1 = px - x0;
            let wy1 = py - y0;
            let wx0 = 1.0 - wx1;
            let wy0 = 1.0 - wy1;
            let in0 = is_inside(x0, y0, width, height);
            let in1 = is_inside(x0 + 1.0, y0, width, height);
            let in2 = is_inside(x0, y0 + 1.0, width, height);
            let in3 = is_inside(x0 + 1.0, y0 + 1.0, width, height);
            let i0 = corner_index(x0, y0, width, height);
            let i1 = corner_index(x0 + 1.0, y0, width, height);
            let i2 = corner_index(x0, y0 + 1.0, width, height);
            let i3 = corner_index(x0 + 1.0, y0 + 1.0, width, height);
            let mut dpx = 0.0f32;
            let mut dpy = 0.0f32;
            for g in 0..groups {
                let ga = grad[((n * groups + g) * kn + k) * hw + p] / f32::cast_from(cg);
                for ci in 0..cg {
                    let base = (n * channels + g * cg + ci) * hw;
                    let r0 = select(in0, right[base + i0], 0.0);
                    let r1 = select(in1, right[base + i1], 0.0);
                    let r2 = select(in2, right[base + i2], 0.0);
                    let r3 = select(in3, right[base + i3], 0.0);
                    let s = wx0 * wy0 * r0 + wx1 * wy0 * r1 + wx0 * wy1 * r2 + wx1 * wy1 * r3;
                    if valid {
                        d_left[base + p] += ga * s;
                    }
                    let lc = ga * left[base + p];
                    dpx += lc * (wy0 * (r1 - r0) + wy1 * (r3 - r2));
                    dpy += lc * (wx0 * (r2 - r0) + wx1 * (r3 - r1));
                    d_right[base + i0].fetch_add(select(in0 && valid, wx0 * wy0 * lc, 0.0));
                    d_right[base + i1].fetch_add(select(in1 && valid, wx1 * wy0 * lc, 0.0));
                    d_right[base + i2].fetch_add(select(in2 && valid, wx0 * wy1 * lc, 0.0));
                    d_right[base + i3].fetch_add(select(in3 && valid, wx1 * wy1 * lc, 0.0));
                }
            }
            if valid {
                d_offset[(n * 2 * kn + 2 * k) * hw + p] = dpx;
                d_offset[(n * 2 * kn + 2 * k + 1) * hw + p] = dpy;
            }
            dfx += dpx;
            dfy += dpy;
        }
        if valid {
            d_flow[(n * 2) * hw + p] = dfx;
            d_flow[(n * 2 + 1) * hw + p] = dfy;
        }
    }
}

#[cube(launch)]
fn warp_kernel(
    right: &Tensor<f32>,
    flow: &Tensor<f32>,
    output: &mut Tensor<f32>,
    units: usize,
    channels: usize,
    height: usize,
    width: usize,
) {
    if ABSOLUTE_POS < units {
        let hw = height * width;
        let p = ABSOLUTE_POS % hw;
        let nc = ABSOLUTE_POS / hw;
        let n = nc / channels;
        let px = f32::cast_from(p % width) + flow[(n * 2) * hw + p];
        let py = f32::cast_from(p / width) + flow[(n * 2 + 1) * hw + p];
        let x0 = px.floor();
        let y0 = py.floor();
        let wx1 = px - x0;
        let wy1 = py - y0;
        let wx0 = 1.0 - wx1;
        let wy0 = 1.0 - wy1;
        let base = nc * hw;
        output[ABSOLUTE_POS] = wx0 * wy0 * corner(right, base, x0, y0, width, height)
            + wx1 * wy0 * corner(right, base, x0 + 1.0, y0, width, height)
            + wx0 * wy1 * corner(right, base, x0, y0 + 1.0, width, height)
            + wx1 * wy1 * corner(right, base, x0 + 1.0, y0 + 1.0, width, height);
    }
}

#[cube(launch)]
fn warp_backward_right_kernel(
    flow: &Tensor<f32>,
    grad: &Tensor<f32>,
    d_right: &mut Tensor<Atomic<f32>>,
    units: usize,
    channels: usize,
    height: usize,
    width: usize,
) {
    // As in the offset backward: spare lanes run at the last element with zero contributions,
    // and no atomic sits under a thread-dependent branch.
    let valid = ABSOLUTE_POS < units;
    let pos = select(valid, ABSOLUTE_POS, units - 1);
    {
        let hw = height * width;
        let p = pos % hw;
        let nc = pos / hw;
        let n = nc / channels;
        let px = f32::cast_from(p % width) + flow[(n * 2) * hw + p];
        let py = f32::cast_from(p / width) + flow[(n * 2 + 1) * hw + p];
        let x0 = px.floor();
        let y0 = py.floor();
        let wx1 = px - x0;
        let wy1 = py - y0;
        let wx0 = 1.0 - wx1;
        let wy0 = 1.0 - wy1;
        let base = nc * hw;
        let g = select(valid, grad[pos], 0.0);
        let inside = is_inside(x0, y0, width, height);
        d_right[base + corner_index(x0, y0, width, height)].fetch_add(select(
            inside,
            wx0 * wy0 * g,
            0.0,
        ));
        let inside = is_inside(x0 + 1.0, y0, width, height);
        d_right[base + corner_index(x0 + 1.0, y0, width, height)].fetch_add(select(
            inside,
            wx1 * wy0 * g,
            0.0,
        ));
        let inside = is_inside(x0, y0 + 1.0, width, height);
        d_right[base + corner_index(x0, y0 + 1.0, width, height)].fetch_add(select(
            inside,
            wx0 * wy1 * g,
            0.0,
        ));
        let inside = is_inside(x0 + 1.0, y0 + 1.0, width, height);
        d_right[base + corner_index(x0 + 1.0, y0 + 1.0, width, height)].fetch_add(select(
            inside,
            wx1 * wy1 * g,
            0.0,
        ));
    }
}

#[cube(launch)]
fn warp_backward_flow_kernel(
    right: &Tensor<f32>,
    flow: &Tensor<f32>,
    grad: &Tensor<f32>,
    d_flow: &mut Tensor<f32>,
    units: usize,
    channels: usize,
    height: usize,
    width: usize,
) {
    if ABSOLUTE_POS < units {
        let hw = height * width;
        let p = ABSOLUTE_POS % hw;
        let n = ABSOLUTE_POS / hw;
        let px = f32::cast_from(p % width) + flow[(n * 2) * hw + p];
        let py = f32::cast_from(p / width) + flow[(n * 2 + 1) * hw + p];
        let x0 = px.floor();
        let y0 = py.floor();
        let wx1 = px - x0;
        let wy1 = py - y0;
        let wx0 = 1.0 - wx1;
        let wy0 = 1.0 - wy1;
        let mut dfx = 0.0f32;
        let mut dfy = 0.0f32;
        for c in 0..channels {
            let base = (n * channels + c) * hw;
            let r0 = corner(right, base, x0, y0, width, height);
            let r1 = corner(right, base, x0 + 1.0, y0, width, height);
            let r2 = corner(right, base, x0, y0 + 1.0, width, height);
            let r3 = corner(right, base, x0 + 1.0, y0 + 1.0, width, height);
            let g = grad[base + p];
            dfx += g * (wy0 * (r1 - r0) + wy1 * (r3 - r2));
            dfy += g * (wx0 * (r2 - r0) + wx1 * (r3 - r1));
        }
        d_flow[(n * 2) * hw + p] = dfx;
        d_flow[(n * 2 + 1) * hw + p] = dfy;
    }
}

fn dims4<R: CubeRuntime>(t: &CubeTensor<R>) -> [usize; 4] {
    t.meta.shape().dims()
}

fn f32_contiguous<R: CubeRuntime>(t: CubeTensor<R>) -> CubeTensor<R> {
    assert_eq!(
        t.dtype,
        DType::F32,
        "AGCL kernels run in float32, got {:?}",
        t.dtype
    );
    into_contiguous(t)
}

fn empty<R: CubeRuntime>(like: &CubeTensor<R>, shape: [usize; 4]) -> CubeTensor<R> {
    empty_device_contiguous_dtype(
        like.client.clone(),
        like.device.clone(),
        Shape::new(shape),
        DType::F32,
    )
}

fn zeros<R: CubeRuntime>(like: &CubeTensor<R>, shape: [usize; 4]) -> CubeTensor<R> {
    zeros_client(
        like.client.clone(),
        like.device.clone(),
        Shape::new(shape),
        DType::F32,
    )
}

fn grid<R: CubeRuntime>(t: &CubeTensor<R>, units: usize) -> (CubeCount, CubeDim) {
    let cube_dim = CubeDim::new(&t.client, units);
    (
        calculate_cube_count_elemwise(&t.client, units, cube_dim),
        cube_dim,
    )
}

impl<R: CubeRuntime, F: FloatElement, I: IntElement, BT: BoolElement> AgclOps
    for CubeBackend<R, F, I, BT>
{
    fn agcl_offset_corr(
        left: CubeTensor<R>,
        right: CubeTensor<R>,
        flow: CubeTensor<R>,
        offset: CubeTensor<R>,
        spec: CorrSpec,
    ) -> CubeTensor<R> {
        let [n, c, h, w] = dims4(&left);
        let kn = spec.candidates();
        let (left, right) = (f32_contiguous(left), f32_contiguous(right));
        let (flow, offset) = (f32_contiguous(flow), f32_contiguous(offset));
        let out = empty(&left, [n, spec.groups * kn, h, w]);
        let units = n * kn * h * w;
        let (count, dim) = grid(&left, units);
        offset_corr_kernel::launch::<R>(
            &left.client,
            count,
            dim,
            left.clone().into_tensor_arg(),
            right.into_tensor_arg(),
            flow.into_tensor_arg(),
            offset.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            units,
            c,
            h,
            w,
            spec.groups,
            spec.rx,
            spec.ry,
        );
        out
    }

    fn agcl_offset_corr_backward(
        left: CubeTensor<R>,
        right: CubeTensor<R>,
        flow: CubeTensor<R>,
        offset: CubeTensor<R>,
        grad: CubeTensor<R>,
        spec: CorrSpec,
        need: [bool; 4],
    ) -> [Option<CubeTensor<R>>; 4] {
        let [n, c, h, w] = dims4(&left);
        let kn = spec.candidates();
        let (left, right) = (f32_contiguous(left), f32_contiguous(right));
        let (flow, offset) = (f32_contiguous(flow), f32_contiguous(offset));
        let grad = f32_contiguous(grad);
        let d_left = zeros(&left, [n, c, h, w]);
        let d_right = zeros(&left, [n, c, h, w]);
        let d_flow = empty(&left, [n, 2, h, w]);
        let d_offset = empty(&left, [n, 2 * kn, h, w]);
        let units = n * h * w;
        let (count, dim) = grid(&left, units);
        offset_corr_backward_kernel::launch::<R>(
            &left.client,
            count,
            dim,
            left.clone().into_tensor_arg(),
            right.into_tensor_arg(),
            flow.into_tensor_arg(),
            offset.into_tensor_arg(),
            grad.into_tensor_arg(),
            d_left.clone().into_tensor_arg(),
            d_right.clone().into_tensor_arg(),
            d_flow.clone().into_tensor_arg(),
            d_offset.clone().into_tensor_arg(),
            units,
            c,
            h,
            w,
            spec.groups,
            spec.rx,
            spec.ry,
        );
        let all = [d_left, d_right, d_flow, d_offset];
        let mut i = 0;
        all.map(|t| {
            i += 1;
            need[i - 1].then_some(t)
        })
    }

    fn agcl_warp(right: CubeTensor<R>, flow: CubeTensor<R>) -> CubeTensor<R> {
        let [n, c, h, w] = dims4(&right);
        let (right, flow) = (f32_contiguous(right), f32_contiguous(flow));
        let out = empty(&right, [n, c, h, w]);
        let units = n * c * h * w;
        let (count, dim) = grid(&right, units);
        warp_kernel::launch::<R>(
            &right.client,
            count,
            dim,
            right.clone().into_tensor_arg(),
            flow.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            units,
            c,
            h,
            w,
        );
        out
    }

    fn agcl_warp_backward(
        right: CubeTensor<R>,
        flow: CubeTensor<R>,
        grad: CubeTensor<R>,
        need: [bool; 2],
    ) -> [Option<CubeTensor<R>>; 2] {
        let [n, c, h, w] = dims4(&right);
        let (right, flow, grad) = (
            f32_contiguous(right),
            f32_contiguous(flow),
            f32_contiguous(grad),
        );
        let d_right = need[0].then(|| {
            let d_right = zeros(&right, [n, c, h, w]);
            let units = n * c * h * w;
            let (count, dim) = grid(&right, units);
            warp_backward_right_kernel::launch::<R>(
                &right.client,
                count,
                dim,
                flow.clone().into_tensor_arg(),
                grad.clone().into_tensor_arg(),
                d_right.clone().into_tensor_arg(),
                units,
                c,
                h,
                w,
            );
            d_right
        });
        let d_flow = need[1].then(|| {
            let d_flow = empty(&right, [n, 2, h, w]);
            let units = n * h * w;
            let (count, dim) = grid(&right, units);
            warp_backward_flow_kernel::launch::<R>(
                &right.client,
                count,
                dim,
                right.clone().into_tensor_arg(),
                flow.clone().into_tensor_arg(),
                grad.clone().into_tensor_arg(),
                d_flow.clone().into_tensor_arg(),
                units,
                c,
                h,
                w,
            );
            d_flow
        });
        [d_right, d_flow]
    }
}

mod fusion {
    //! `Fusion<B>`: each call becomes one custom operation in the fusion stream; it runs the
    //! inner backend's kernel when the stream executes.

    use burn::tensor::Shape;
    use burn_fusion::stream::{Operation, OperationStreams};
    use burn_fusion::{Fusion, FusionBackend, FusionRuntime};
    use burn_ir::{CustomOpIr, HandleContainer, OperationIr, TensorIr};

    use super::super::{AgclOps, CorrSpec};
    use burn::tensor::ops::FloatTensor;

    type Handles<B> =
        HandleContainer<<<B as FusionBackend>::FusionRuntime as FusionRuntime>::FusionHandle>;

    #[derive(Clone, Debug)]
    enum Call {
        OffsetCorr(CorrSpec),
        OffsetCorrBackward(CorrSpec, [bool; 4]),
        Warp,
        WarpBackward([bool; 2]),
    }

    #[derive(Clone, Debug)]
    struct AgclOp<B> {
        desc: CustomOpIr,
        call: Call,
        _backend: core::marker::PhantomData<B>,
    }

    impl<B: FusionBackend + AgclOps> Operation<B::FusionRuntime> for AgclOp<B> {
        fn execute(&self, handles: &mut Handles<B>) {
            let mut inputs = self
                .desc
                .inputs
                .iter()
                .map(|t| handles.get_float_tensor::<B>(t));
            let mut next = || inputs.next().expect("AGCL fusion: input count");
            let outputs: Vec<FloatTensor<B>> = match self.call.clone() {
                Call::OffsetCorr(spec) => {
                    vec![B::agcl_offset_corr(next(), next(), next(), next(), spec)]
                }
                Call::OffsetCorrBackward(spec, need) => {
                    let (l, r, f, o, g) = (next(), next(), next(), next(), next());
                    B::agcl_offset_corr_backward(l, r, f, o, g, spec, need)
                        .into_iter()
                        .flatten()
                        .collect()
                }
                Call::Warp => vec![B::agcl_warp(next(), next())],
                Call::WarpBackward(need) => {
                    let (r, f, g) = (next(), next(), next());
                    B::agcl_warp_backward(r, f, g, need)
                        .into_iter()
                        .flatten()
                        .collect()
                }
            };
            for (ir, t) in self.desc.outputs.iter().zip(outputs) {
                handles.register_float_tensor::<B>(&ir.id, t);
            }
        }
    }

    /// Registers `call` on `inputs` with outputs of the given shapes (all float32).
    fn register<B: FusionBackend + AgclOps>(
        name: &'static str,
        call: Call,
        inputs: Vec<FloatTensor<Fusion<B>>>,
        shapes: Vec<[usize; 4]>,
    ) -> Vec<FloatTensor<Fusion<B>>> {
        let client = inputs[0].client.clone();
        let dtype = inputs[0].dtype;
        let streams = OperationStreams::with_inputs(inputs.iter());
        let outputs: Vec<TensorIr> = shapes
            .into_iter()
            .map(|s| TensorIr::uninit(client.create_empty_handle(), Shape::new(s), dtype))
            .collect();
        let inputs: Vec<TensorIr> = inputs.into_iter().map(|t| t.into_ir()).collect();
        let desc = CustomOpIr::new(name, &inputs, &outputs);
        client.register(
            streams,
            OperationIr::Custom(desc.clone()),
            AgclOp::<B> {
                desc,
                call,
                _backend: core::marker::PhantomData,
            },
        )
    }

    fn dims<B: burn::tensor::backend::Backend>(t: &FloatTensor<B>) -> [usize; 4] {
        burn::tensor::TensorMetadata::shape(t).dims()
    }

    impl<B: FusionBackend + AgclOps> AgclOps for Fusion<B> {
        fn agcl_offset_corr(
            left: FloatTensor<Self>,
            right: FloatTensor<Self>,
            flow: FloatTensor<Self>,
            offset: FloatTensor<Self>,
            spec: CorrSpec,
        ) -> FloatTensor<Self> {
            let [n, _, h, w] = dims::<Self>(&left);
            let shape = [n, spec.groups * spec.candidates(), h, w];
            register::<B>(
                "crestereo_agcl_offset_corr",
                Call::OffsetCorr(spec),
                vec![left, right, flow, offset],
                vec![shape],
            )
            .remove(0)
        }

        fn agcl_offset_corr_backward(
            left: FloatTensor<Self>,
            right: FloatTensor<Self>,
            flow: FloatTensor<Self>,
            offset: FloatTensor<Self>,
            grad: FloatTensor<Self>,
            spec: CorrSpec,
            need: [bool; 4],
        ) -> [Option<FloatTensor<Self>>; 4] {
            let shapes = [&left, &right, &flow, &offset].map(dims::<Self>);
            let wanted: Vec<[usize; 4]> = shapes
                .iter()
                .zip(need)
                .filter(|(_, n)| *n)
                .map(|(s, _)| *s)
                .collect();
            let mut out = register::<B>(
                "crestereo_agcl_offset_corr_backward",
                Call::OffsetCorrBackward(spec, need),
                vec![left, right, flow, offset, grad],
                wanted,
            )
            .into_iter();
            need.map(|n| if n { out.next() } else { None })
        }

        fn agcl_warp(right: FloatTensor<Self>, flow: FloatTensor<Self>) -> FloatTensor<Self> {
            let shape = dims::<Self>(&right);
            register::<B>(
                "crestereo_agcl_warp",
                Call::Warp,
                vec![right, flow],
                vec![shape],
            )
            .remove(0)
        }

        fn agcl_warp_backward(
            right: FloatTensor<Self>,
            flow: FloatTensor<Self>,
            grad: FloatTensor<Self>,
            need: [bool; 2],
        ) -> [Option<FloatTensor<Self>>; 2] {
            let shapes = [dims::<Self>(&right), dims::<Self>(&flow)];
            let wanted: Vec<[usize; 4]> = shapes
                .iter()
                .zip(need)
                .filter(|(_, n)| *n)
                .map(|(s, _)| *s)
                .collect();
            let mut out = register::<B>(
                "crestereo_agcl_warp_backward",
                Call::WarpBackward(need),
                vec![right, flow, grad],
                wanted,
            )
            .into_iter();
            need.map(|n| if n { out.next() } else { None })
        }
    }
}
