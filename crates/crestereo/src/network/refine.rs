//! One level of the refinement cascade: the iterations at 1/16, 1/8 or 1/4 and the hand-over of
//! the flow from one level to the next, with the reference's signs and gradient cuts.

use burn::prelude::*;

use crate::export::onnx::{Graph, Value};
use crate::network::attention::{LoFTREncoderLayer, emit_from_tokens, emit_to_tokens, from_tokens};
use crate::network::corr::{AdaptiveGroupCorrelation, SearchWindow};
pub use crate::network::level::Level;
use crate::network::observer::{ForwardObserver, IterationOutputs};
use crate::network::update::UpdateBlock;
use crate::ops::agcl::CorrSpec;
use crate::ops::agcl::emit::{emit_offset_corr, emit_shift_corr, emit_warp};
use crate::ops::upsample::{
    convex_upsample, emit_convex_upsample, emit_resize_bilinear_align_corners,
    resize_bilinear_align_corners,
};

/// How a level looks up correlation around the current flow.
pub(crate) enum Lookup<B: Backend> {
    /// 1/16: cross-attention between the (self-attended) maps before every lookup, then
    /// learned offsets (N, 18, h, w) around each window candidate.
    AttendedOffsets {
        corr: AdaptiveGroupCorrelation<B>,
        offsets: Tensor<B, 4>,
    },
    /// 1/8: learned offsets around each window candidate.
    Offsets {
        corr: AdaptiveGroupCorrelation<B>,
        offsets: Tensor<B, 4>,
    },
    /// 1/4: the right map warped by the flow, then shifted by the window's integer offsets.
    Warp { corr: AdaptiveGroupCorrelation<B> },
}

impl<B: Backend> Lookup<B> {
    pub(crate) fn level(&self) -> Level {
        match self {
            Lookup::AttendedOffsets { .. } => Level::Sixteenth,
            Lookup::Offsets { .. } => Level::Eighth,
            Lookup::Warp { .. } => Level::Quarter,
        }
    }

    fn correlation(&self) -> &AdaptiveGroupCorrelation<B> {
        match self {
            Lookup::AttendedOffsets { corr, .. }
            | Lookup::Offsets { corr, .. }
            | Lookup::Warp { corr } => corr,
        }
    }
}

/// Everything one level refines with.
pub(crate) struct LevelInputs<B: Backend> {
    pub lookup: Lookup<B>,
    /// The update block's initial hidden state (N, hidden, h, w).
    pub net: Tensor<B, 4>,
    /// The context features (N, context, h, w), the same at every iteration.
    pub inp: Tensor<B, 4>,
}

impl<B: Backend> LevelInputs<B> {
    /// (h, w) of this level.
    pub(crate) fn size(&self) -> [usize; 2] {
        let [_, _, h, w] = self.lookup.correlation().fmap1.dims();
        [h, w]
    }

    /// A zero flow at this level (N, 2, h, w), where the cascade starts.
    pub(crate) fn zero_flow(&self) -> Tensor<B, 4> {
        let [h, w] = self.size();
        let net = &self.net;
        Tensor::zeros([net.dims()[0], 2, h, w], (&net.device(), net.dtype()))
    }
}

/// The hand-over to the next level (and of a `flow_init`): `-scale · resize(flow, size)` with
/// `scale = size_h / flow_h`, bilinear with align_corners. The sign flips because the internal
/// flow alternates between negative and positive disparity from level to level.
pub(crate) fn hand_over<B: Backend>(flow: Tensor<B, 4>, size: [usize; 2]) -> Tensor<B, 4> {
    let factor = hand_over_factor(flow.dims()[2], size);
    resize_bilinear_align_corners(flow, size).mul_scalar(factor)
}

/// The factor of [`hand_over`] from a flow of height `from_h` to `size`: `-size_h / from_h`.
fn hand_over_factor(from_h: usize, size: [usize; 2]) -> f64 {
    -(size[0] as f64 / from_h as f64)
}

/// A convex-upsampled flow of `level` as a full-resolution prediction whose channel 0 is the
/// positive disparity: `-f · resize×f(flow)`, just `-flow` at 1/4.
fn full_resolution<B: Backend>(upsampled: Tensor<B, 4>, level: Level) -> Tensor<B, 4> {
    match level.full_resolution_factor() {
        1 => upsampled.neg(),
        f => {
            let [_, _, h, w] = upsampled.dims();
            resize_bilinear_align_corners(upsampled, [f * h, f * w]).mul_scalar(-(f as f64))
        }
    }
}

/// What the refinement reads of the network, borrowed from [`crate::CREStereo`] for one pass
/// (the levels' iterations, the 1/16 cross-attention and the convex upsampling).
pub(crate) struct Refiner<'a, B: Backend> {
    pub update_block: &'a UpdateBlock<B>,
    pub cross_attention: &'a LoFTREncoderLayer<B>,
    pub groups: usize,
    pub upsample_rate: usize,
}

impl<B: Backend> Refiner<'_, B> {
    /// Runs `iters` iterations at one level from `flow` (N, 2, h, w). Every iteration detaches
    /// the flow (the reference cuts the gradient there), looks up the correlation in the window
    /// of that iteration, runs the update block and pushes a full-resolution prediction.
    /// Returns the last flow convex-upsampled ×rate, which the next level takes over (zeros of
    /// that size when `iters` is 0, as the flow starts from zero then).
    pub(crate) fn refine_level(
        &self,
        level: LevelInputs<B>,
        mut flow: Tensor<B, 4>,
        iters: usize,
        predictions: &mut Vec<Tensor<B, 4>>,
        observer: &mut dyn ForwardObserver<B>,
    ) -> Tensor<B, 4> {
        let LevelInputs {
            lookup,
            mut net,
            inp,
        } = level;
        let rate = self.upsample_rate;
        let mut upsampled = None;
        for index in 0..iters {
            flow = flow.detach();
            let corr = self.look_up(&lookup, flow.clone(), index, observer);
            let (net_new, up_mask, delta_flow) =
                self.update_block
                    .forward(net, inp.clone(), corr.clone(), flow.clone());
            net = net_new;
            let step = IterationOutputs {
                level: lookup.level(),
                index,
                corr: &corr,
                delta_flow: &delta_flow,
                up_mask: &up_mask,
                net: &net,
            };
            observer.iteration(&step);
            flow = flow + delta_flow;
            let up = convex_upsample(flow.clone(), up_mask, rate);
            predictions.push(full_resolution(up.clone(), lookup.level()));
            upsampled = Some(up);
        }
        upsampled.unwrap_or_else(|| {
            let [n, _, h, w] = flow.dims();
            Tensor::zeros([n, 2, h * rate, w * rate], (&flow.device(), flow.dtype()))
        })
    }

    /// The correlation volume of iteration `index` around `flow`.
    fn look_up(
        &self,
        lookup: &Lookup<B>,
        flow: Tensor<B, 4>,
        index: usize,
        observer: &mut dyn ForwardObserver<B>,
    ) -> Tensor<B, 4> {
        let window = SearchWindow::for_iteration(index);
        match lookup {
            Lookup::AttendedOffsets { corr, offsets } => {
                let [_, _, h, w] = corr.fmap1.dims();
                let (left, right) = corr.cross_attend(self.cross_attention);
                observer.cross_attention(index, &left, &right);
                corr.corr_offset_maps(
                    from_tokens(left, h, w),
                    from_tokens(right, h, w),
                    flow,
                    offsets.clone(),
                    window,
                )
            }
            Lookup::Offsets { corr, offsets } => corr.corr_offset(flow, offsets.clone(), window),
            Lookup::Warp { corr } => corr.corr_warp(flow, window),
        }
    }
}

/// A level's lookup as graph values (see [`Lookup`]).
pub(crate) enum EmittedLookup {
    /// 1/16: the self-attended maps, cross-attended once (the inputs of the cross-attention are
    /// the same at every iteration, so its result is too) and learned offsets.
    AttendedOffsets {
        left: Value,
        right: Value,
        offsets: Value,
    },
    Offsets {
        left: Value,
        right: Value,
        offsets: Value,
    },
    Warp {
        left: Value,
        right: Value,
    },
}

/// A level's inputs as graph values (see [`LevelInputs`]).
pub(crate) struct EmittedLevel {
    pub lookup: EmittedLookup,
    pub net: Value,
    pub inp: Value,
}

impl EmittedLevel {
    pub(crate) fn size(&self) -> [usize; 2] {
        let [_, _, h, w] = self.net.dims();
        [h, w]
    }
}

/// [`hand_over`] as ONNX nodes.
pub(crate) fn emit_hand_over(g: &mut Graph, flow: &Value, size: [usize; 2]) -> Value {
    let factor = hand_over_factor(flow.shape[2], size);
    let resized = emit_resize_bilinear_align_corners(g, flow, size);
    g.mul_scalar(&resized, factor as f32)
}

impl<B: Backend> Refiner<'_, B> {
    /// [`Self::refine_level`] as ONNX nodes, for inference: returns the last flow
    /// convex-upsampled ×rate (the predictions of the other iterations feed nothing, so they
    /// are not emitted).
    pub(crate) fn emit_refine_level(
        &self,
        g: &mut Graph,
        level: EmittedLevel,
        mut flow: Value,
        iters: usize,
    ) -> Value {
        let rate = self.upsample_rate;
        if iters == 0 {
            let [n, _, h, w] = flow.dims();
            return g.zeros(&[n, 2, h * rate, w * rate]);
        }
        let EmittedLevel {
            lookup,
            mut net,
            inp,
        } = level;
        let lookup = match lookup {
            EmittedLookup::AttendedOffsets {
                left,
                right,
                offsets,
            } => {
                let [_, _, h, w] = left.dims();
                let left_tokens = emit_to_tokens(g, &left);
                let right_tokens = emit_to_tokens(g, &right);
                let (l, r) = self
                    .cross_attention
                    .emit_cross(g, &left_tokens, &right_tokens);
                EmittedLookup::Offsets {
                    left: emit_from_tokens(g, &l, h, w),
                    right: emit_from_tokens(g, &r, h, w),
                    offsets,
                }
            }
            other => other,
        };
        let groups = self.groups;
        let mut upsampled = None;
        for index in 0..iters {
            let spec = CorrSpec::new(SearchWindow::for_iteration(index), groups);
            let corr = match &lookup {
                EmittedLookup::Offsets {
                    left,
                    right,
                    offsets,
                } => emit_offset_corr(g, left, right, &flow, offsets, spec),
                EmittedLookup::Warp { left, right } => {
                    let warped = emit_warp(g, right, &flow);
                    emit_shift_corr(g, left, &warped, spec)
                }
                EmittedLookup::AttendedOffsets { .. } => unreachable!("cross-attended above"),
            };
            let last = index + 1 == iters;
            let (net_new, up_mask, delta_flow) =
                self.update_block.emit(g, &net, &inp, &corr, &flow, last);
            net = net_new;
            flow = g.add(&flow, &delta_flow);
            if let Some(mask) = up_mask {
                upsampled = Some(emit_convex_upsample(g, &flow, &mask, rate));
            }
        }
        upsampled.expect("the last iteration's upsampled flow")
    }
}
