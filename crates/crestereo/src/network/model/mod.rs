//! The CREStereo network: encoder, 1/16 attention, AGCL, shared update block and the
//! three-level cascade (1/16 → 1/8 → 1/4) with the reference's exact hand-over
//! (the levels themselves are in [`crate::network::refine`]).

use burn::prelude::*;
use burn::tensor::activation::{relu, tanh};
use burn::tensor::module::avg_pool2d;

use crate::export::onnx::{Graph, Value};
use crate::network::attention::{
    LoFTREncoderLayer, LoFTREncoderLayerConfig, emit_from_tokens, emit_to_tokens, from_tokens,
    to_tokens,
};
use crate::network::corr::AdaptiveGroupCorrelationConfig;
use crate::network::encoder::{BasicEncoder, BasicEncoderConfig, conv_cfg};
use crate::network::formula;
use crate::network::observer::{ForwardObserver, NoObserver};
use crate::network::position_encoding::{PositionEncodingSine, PositionEncodingSineConfig};
use crate::network::refine::{
    EmittedLevel, EmittedLookup, Level, LevelInputs, Lookup, Refiner, emit_hand_over, hand_over,
};
use crate::network::update::{UpdateBlock, UpdateBlockConfig};
use crate::ops::conv2d::Conv2d;

#[derive(Config, Debug)]
pub struct CREStereoConfig {
    #[config(default = 128)]
    pub hidden_dim: usize,
    #[config(default = 128)]
    pub context_dim: usize,
    /// Encoder output channels (= hidden + context).
    #[config(default = 256)]
    pub feature_dim: usize,
    #[config(default = 8)]
    pub nhead: usize,
    #[config(default = 4)]
    pub groups: usize,
    /// Search candidates per group (1×9 or 3×3).
    #[config(default = 9)]
    pub search_num: usize,
    /// Convex upsampling factor of every level.
    #[config(default = 4)]
    pub upsample_rate: usize,
    /// Learned offsets are mapped to (−range, range).
    #[config(default = 1.0)]
    pub offset_range: f64,
    /// Reproduce LoFTR's positional-encoding frequency quirk (`false` = reference behaviour).
    #[config(default = false)]
    pub pos_encoding_bug_fix: bool,
}

#[derive(Module, Debug)]
pub struct CREStereo<B: Backend> {
    pub fnet: BasicEncoder<B>,
    pub update_block: UpdateBlock<B>,
    pub self_att_fn: LoFTREncoderLayer<B>,
    pub cross_att_fn: LoFTREncoderLayer<B>,
    pub conv_offset_16: Conv2d<B>,
    pub conv_offset_8: Conv2d<B>,
    pub pos_encoding: PositionEncodingSine,
    pub hidden_dim: usize,
    pub groups: usize,
    pub upsample_rate: usize,
    pub offset_range: f64,
}

/// Held while a network draws its initial weights. Burn's backends draw them from one
/// process-wide RNG, and lazily, when a parameter is first read: a network built in another
/// thread at the same time (a checkpoint being loaded, a test) would take draws from the
/// middle of a seeded initialisation and change its weights.
static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());

impl CREStereoConfig {
    /// A network with freshly drawn weights (all drawn before this returns).
    pub fn init<B: Backend>(&self, device: &B::Device) -> CREStereo<B> {
        let _guard = INIT.lock().unwrap_or_else(|e| e.into_inner());
        self.draw(device)
    }

    /// A network whose initial weights depend only on `seed` (and this config), whatever
    /// other threads of the process do meanwhile — as long as they build networks through
    /// this config and draw no random tensors of their own.
    pub fn init_seeded<B: Backend>(&self, seed: u64, device: &B::Device) -> CREStereo<B> {
        let _guard = INIT.lock().unwrap_or_else(|e| e.into_inner());
        B::seed(device, seed);
        self.draw(device)
    }

    /// Builds the network and reads every parameter once, so that all its random draws
    /// happen now (under the caller's lock) rather than on first use.
    fn draw<B: Backend>(&self, device: &B::Device) -> CREStereo<B> {
        struct Materialise;
        impl<B: Backend> burn::module::ModuleVisitor<B> for Materialise {
            fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<B, D>>) {
                let _ = param.val();
            }
        }
        let model = self.build(device);
        model.visit(&mut Materialise);
        model
    }

    fn build<B: Backend>(&self, device: &B::Device) -> CREStereo<B> {
        assert_eq!(self.hidden_dim + self.context_dim, self.feature_dim);
        let att = LoFTREncoderLayerConfig::new()
            .with_d_model(self.feature_dim)
            .with_nhead(self.nhead);
        CREStereo {
            fnet: BasicEncoderConfig::new()
                .with_output_dim(self.feature_dim)
                .init(device),
            update_block: UpdateBlockConfig::new()
                .with_hidden_dim(self.hidden_dim)
                .with_cor_planes(self.groups * self.search_num)
                .with_mask_size(self.upsample_rate)
                .init(device),
            self_att_fn: att.init(device),
            cross_att_fn: att.init(device),
            conv_offset_16: conv_cfg(self.feature_dim, self.search_num * 2, [3, 3], 1, [1, 1])
                .init(device),
            conv_offset_8: conv_cfg(self.feature_dim, self.search_num * 2, [3, 3], 1, [1, 1])
                .init(device),
            pos_encoding: PositionEncodingSineConfig::new()
                .with_d_model(self.feature_dim)
                .with_temp_bug_fix(self.pos_encoding_bug_fix)
                .init(),
            hidden_dim: self.hidden_dim,
            groups: self.groups,
            upsample_rate: self.upsample_rate,
            offset_range: self.offset_range,
        }
    }
}

/// The inputs of the three levels of one forward pass.
struct Levels<B: Backend> {
    quarter: LevelInputs<B>,
    eighth: LevelInputs<B>,
    sixteenth: LevelInputs<B>,
}

fn pool<B: Backend>(x: Tensor<B, 4>, k: usize) -> Tensor<B, 4> {
    avg_pool2d(x, [k, k], [k, k], [0, 0], true, false)
}

impl<B: Backend> CREStereo<B> {
    /// Runs the network. `left`, `right`: (N, 3, H, W) BGR in 0..255, H and W multiples of 16.
    ///
    /// Without `flow_init`: `iters / 2` iterations at 1/16, `iters / 2` at 1/8 and `iters` at 1/4,
    /// returning `2·iters` full-resolution predictions (N, 2, H, W) whose channel 0 is the
    /// positive disparity. With `flow_init` (N, 2, h, w) — a previous prediction at any
    /// resolution — only the 1/4 level runs (`iters` predictions).
    pub fn forward(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        iters: usize,
        flow_init: Option<Tensor<B, 4>>,
    ) -> Vec<Tensor<B, 4>> {
        self.forward_observed(left, right, iters, flow_init, &mut NoObserver)
    }

    /// [`Self::forward`] that shows its intermediates to `observer`.
    pub fn forward_observed(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        iters: usize,
        flow_init: Option<Tensor<B, 4>>,
        observer: &mut dyn ForwardObserver<B>,
    ) -> Vec<Tensor<B, 4>> {
        check_pair(&left, &right);
        let (fmap1, fmap2) = self.encode(left, right, observer);
        let Levels {
            quarter,
            eighth,
            sixteenth,
        } = self.levels(fmap1, fmap2, observer);
        let mut predictions = Vec::with_capacity(2 * iters);
        let flow = match flow_init {
            Some(init) => hand_over(init, quarter.size()),
            None => {
                let start = sixteenth.zero_flow();
                let flow = self.refiner().refine_level(
                    sixteenth,
                    start,
                    iters / 2,
                    &mut predictions,
                    observer,
                );
                let flow = hand_over(flow, eighth.size());
                let flow = self.refiner().refine_level(
                    eighth,
                    flow,
                    iters / 2,
                    &mut predictions,
                    observer,
                );
                hand_over(flow, quarter.size())
            }
        };
        self.refiner()
            .refine_level(quarter, flow, iters, &mut predictions, observer);
        predictions
    }

    /// The parts of the network the refinement levels read.
    fn refiner(&self) -> Refiner<'_, B> {
        Refiner {
            update_block: &self.update_block,
            cross_attention: &self.cross_att_fn,
            groups: self.groups,
            upsample_rate: self.upsample_rate,
        }
    }

    /// The encoder's 1/4 maps of both images, normalised to −1..1 first as the reference does.
    fn encode(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        observer: &mut dyn ForwardObserver<B>,
    ) -> (Tensor<B, 4>, Tensor<B, 4>) {
        let norm = |x| formula::apply(x, &formula::INPUT_NORMALISATION);
        let (fmap1, fmap2) = self.fnet.forward_pair(norm(left), norm(right));
        observer.features(&fmap1, &fmap2);
        (fmap1, fmap2)
    }

    /// The three levels' inputs, in the reference's order of operations. 1/8 and 1/16 are
    /// average pools of the 1/4 maps; the left 1/4 map splits into hidden state (tanh) and
    /// context (relu); the 1/16 maps are self-attended before their correlation is set up.
    fn levels(
        &self,
        fmap1: Tensor<B, 4>,
        fmap2: Tensor<B, 4>,
        observer: &mut dyn ForwardObserver<B>,
    ) -> Levels<B> {
        let [n, c, h4, w4] = fmap1.dims();
        let hd = self.hidden_dim;
        let fmap1_dw8 = pool(fmap1.clone(), 2);
        let fmap2_dw8 = pool(fmap2.clone(), 2);
        let offset_dw8 = self.learned_offsets(
            &self.conv_offset_8,
            Level::Eighth,
            fmap1_dw8.clone(),
            observer,
        );

        let net = tanh(fmap1.clone().slice([0..n, 0..hd, 0..h4, 0..w4]));
        let inp = relu(fmap1.clone().slice([0..n, hd..c, 0..h4, 0..w4]));
        let net_dw8 = pool(net.clone(), 2);
        let inp_dw8 = pool(inp.clone(), 2);

        let fmap1_dw16 = pool(fmap1.clone(), 4);
        let fmap2_dw16 = pool(fmap2.clone(), 4);
        let offset_dw16 = self.learned_offsets(
            &self.conv_offset_16,
            Level::Sixteenth,
            fmap1_dw16.clone(),
            observer,
        );
        let net_dw16 = pool(net.clone(), 4);
        let inp_dw16 = pool(inp.clone(), 4);
        let (fmap1_dw16, fmap2_dw16) = self.self_attend(fmap1_dw16, fmap2_dw16, observer);

        let agcl = AdaptiveGroupCorrelationConfig::new().with_groups(self.groups);
        Levels {
            quarter: LevelInputs {
                lookup: Lookup::Warp {
                    corr: agcl.init(fmap1, fmap2),
                },
                net,
                inp,
            },
            eighth: LevelInputs {
                lookup: Lookup::Offsets {
                    corr: agcl.init(fmap1_dw8, fmap2_dw8),
                    offsets: offset_dw8,
                },
                net: net_dw8,
                inp: inp_dw8,
            },
            sixteenth: LevelInputs {
                lookup: Lookup::AttendedOffsets {
                    corr: agcl.init(fmap1_dw16, fmap2_dw16),
                    offsets: offset_dw16,
                },
                net: net_dw16,
                inp: inp_dw16,
            },
        }
    }

    /// A level's learned offsets `(sigmoid(conv(x)) − 0.5) · 2 · range`, in (−range, range).
    fn learned_offsets(
        &self,
        conv: &Conv2d<B>,
        level: Level,
        x: Tensor<B, 4>,
        observer: &mut dyn ForwardObserver<B>,
    ) -> Tensor<B, 4> {
        let logits = conv.forward(x);
        observer.offset_logits(level, &logits);
        formula::apply(logits, &formula::learned_offsets(self.offset_range))
    }

    /// Positional encoding, then self-attention, on the 1/16 maps.
    fn self_attend(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        observer: &mut dyn ForwardObserver<B>,
    ) -> (Tensor<B, 4>, Tensor<B, 4>) {
        let [_, _, h, w] = left.dims();
        let table = self.pos_encoding.table_tensor::<B>(h, w, &left.device());
        let table = crate::ops::float_like(table, left.dtype());
        observer.positional_encoding(&table);
        let (left, right) = self.self_att_fn.forward_self(
            to_tokens(self.pos_encoding.add(left, &table)),
            to_tokens(self.pos_encoding.add(right, &table)),
        );
        observer.self_attention(&left, &right);
        (from_tokens(left, h, w), from_tokens(right, h, w))
    }
}

impl<B: Backend> CREStereo<B> {
    /// [`Self::forward`] as ONNX nodes, returning only the last prediction (N, 2, H, W), the
    /// one inference keeps. `iters` must be at least 1.
    pub fn emit_forward(
        &self,
        g: &mut Graph,
        left: &Value,
        right: &Value,
        iters: usize,
        flow_init: Option<&Value>,
    ) -> Value {
        assert!(iters >= 1, "at least one iteration");
        let [_, ch, h, w] = left.dims();
        assert_eq!(
            left.shape, right.shape,
            "CREStereo: left and right images differ in shape"
        );
        assert!(
            ch == 3 && h % 16 == 0 && w % 16 == 0,
            "CREStereo: image size {h}x{w}"
        );
        let left = formula::emit(g, left, &formula::INPUT_NORMALISATION);
        let right = formula::emit(g, right, &formula::INPUT_NORMALISATION);
        let (fmap1, fmap2) = self.fnet.emit_pair(g, &left, &right);
        let [quarter, eighth, sixteenth] = self.emit_levels(g, fmap1, fmap2);
        let flow = match flow_init {
            Some(init) => emit_hand_over(g, init, quarter.size()),
            None => {
                let [n, _, h16, w16] = sixteenth.net.dims();
                let start = g.zeros(&[n, 2, h16, w16]);
                let flow = self
                    .refiner()
                    .emit_refine_level(g, sixteenth, start, iters / 2);
                let flow = emit_hand_over(g, &flow, eighth.size());
                let flow = self.refiner().emit_refine_level(g, eighth, flow, iters / 2);
                emit_hand_over(g, &flow, quarter.size())
            }
        };
        let up = self.refiner().emit_refine_level(g, quarter, flow, iters);
        g.neg(&up)
    }

    /// [`Self::levels`] as ONNX nodes: the 1/4, 1/8 and 1/16 inputs.
    fn emit_levels(&self, g: &mut Graph, fmap1: Value, fmap2: Value) -> [EmittedLevel; 3] {
        let [_, c, _, _] = fmap1.dims();
        let hd = self.hidden_dim;
        let offsets = |g: &mut Graph, conv: &Conv2d<B>, x: &Value| {
            let logits = conv.emit(g, x);
            formula::emit(g, &logits, &formula::learned_offsets(self.offset_range))
        };
        let fmap1_dw8 = g.avg_pool(&fmap1, 2);
        let fmap2_dw8 = g.avg_pool(&fmap2, 2);
        let offset_dw8 = offsets(g, &self.conv_offset_8, &fmap1_dw8);

        let net = g.narrow(&fmap1, 1, 0, hd);
        let net = g.tanh(&net);
        let inp = g.narrow(&fmap1, 1, hd, c - hd);
        let inp = g.relu(&inp);
        let net_dw8 = g.avg_pool(&net, 2);
        let inp_dw8 = g.avg_pool(&inp, 2);

        let fmap1_dw16 = g.avg_pool(&fmap1, 4);
        let fmap2_dw16 = g.avg_pool(&fmap2, 4);
        let offset_dw16 = offsets(g, &self.conv_offset_16, &fmap1_dw16);
        let net_dw16 = g.avg_pool(&net, 4);
        let inp_dw16 = g.avg_pool(&inp, 4);
        let [_, _, h16, w16] = fmap1_dw16.dims();
        let left = self.pos_encoding.emit(g, &fmap1_dw16);
        let right = self.pos_encoding.emit(g, &fmap2_dw16);
        let left = emit_to_tokens(g, &left);
        let right = emit_to_tokens(g, &right);
        let (left, right) = self.self_att_fn.emit_self(g, &left, &right);
        let fmap1_dw16 = emit_from_tokens(g, &left, h16, w16);
        let fmap2_dw16 = emit_from_tokens(g, &right, h16, w16);
        [
            EmittedLevel {
                lookup: EmittedLookup::Warp {
                    left: fmap1,
                    right: fmap2,
                },
                net,
                inp,
            },
            EmittedLevel {
                lookup: EmittedLookup::Offsets {
                    left: fmap1_dw8,
                    right: fmap2_dw8,
                    offsets: offset_dw8,
                },
                net: net_dw8,
                inp: inp_dw8,
            },
            EmittedLevel {
                lookup: EmittedLookup::AttendedOffsets {
                    left: fmap1_dw16,
                    right: fmap2_dw16,
                    offsets: offset_dw16,
                },
                net: net_dw16,
                inp: inp_dw16,
            },
        ]
    }
}

fn check_pair<B: Backend>(left: &Tensor<B, 4>, right: &Tensor<B, 4>) {
    let [_, ch, h, w] = left.dims();
    assert_eq!(
        left.dims(),
        right.dims(),
        "CREStereo: left and right images differ in shape"
    );
    assert_eq!(ch, 3, "CREStereo: expected 3-channel images");
    assert!(
        h % 16 == 0 && w % 16 == 0,
        "CREStereo: image size {h}x{w} is not a multiple of 16"
    );
}

#[cfg(test)]
mod emit_tests;
