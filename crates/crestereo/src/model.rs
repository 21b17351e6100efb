//! The CREStereo network: encoder, 1/16 attention, AGCL, shared update block and the
//! three-level cascade (1/16 → 1/8 → 1/4) with the reference's exact hand-over.

use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid, tanh};
use burn::tensor::module::avg_pool2d;

use crate::attention::{LoFTREncoderLayer, LoFTREncoderLayerConfig, from_tokens, to_tokens};
use crate::corr::{AdaptiveGroupCorrelationConfig, SearchWindow};
use crate::encoder::{BasicEncoder, BasicEncoderConfig, conv_cfg};
use crate::position_encoding::{PositionEncodingSine, PositionEncodingSineConfig};
use crate::update::{UpdateBlock, UpdateBlockConfig};
use crate::upsample::{convex_upsample, resize_bilinear_align_corners};

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
    /// Run the feature encoder and the attention layers in float64 (outputs cast back to the
    /// model dtype). Slower; makes parameter gradients match exact arithmetic to ~1e-5 instead
    /// of ~5e-3 for the encoder (see `BasicEncoderConfig::compute_f64`). Forward unchanged to ~1e-6.
    #[config(default = false)]
    pub f64_features: bool,
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

impl CREStereoConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> CREStereo<B> {
        assert_eq!(self.hidden_dim + self.context_dim, self.feature_dim);
        let att = LoFTREncoderLayerConfig::new()
            .with_d_model(self.feature_dim)
            .with_nhead(self.nhead)
            .with_compute_f64(self.f64_features);
        CREStereo {
            fnet: BasicEncoderConfig::new()
                .with_output_dim(self.feature_dim)
                .with_compute_f64(self.f64_features)
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

/// Optional record of every intermediate of one forward pass (for parity tests and debugging).
#[derive(Debug)]
pub struct Trace<B: Backend> {
    pub fmap1: Option<Tensor<B, 4>>,
    pub fmap2: Option<Tensor<B, 4>>,
    /// Positional encoding table (d_model, H/16, W/16).
    pub pos_encoding: Option<Tensor<B, 3>>,
    pub selfatt_left_tokens: Option<Tensor<B, 3>>,
    pub selfatt_right_tokens: Option<Tensor<B, 3>>,
    /// Output tokens of the first cross-attention call (1/16, iteration 0).
    pub crossatt_left_tokens_call0: Option<Tensor<B, 3>>,
    pub crossatt_right_tokens_call0: Option<Tensor<B, 3>>,
    pub conv_offset_16_raw: Option<Tensor<B, 4>>,
    pub conv_offset_8_raw: Option<Tensor<B, 4>>,
    /// Every correlation call, in order.
    pub corr: Vec<Tensor<B, 4>>,
    /// Every update-block call: Δflow, up-mask and new hidden state.
    pub delta_flow: Vec<Tensor<B, 4>>,
    pub up_mask: Vec<Tensor<B, 4>>,
    pub net: Vec<Tensor<B, 4>>,
}

impl<B: Backend> Default for Trace<B> {
    fn default() -> Self {
        Self {
            fmap1: None,
            fmap2: None,
            pos_encoding: None,
            selfatt_left_tokens: None,
            selfatt_right_tokens: None,
            crossatt_left_tokens_call0: None,
            crossatt_right_tokens_call0: None,
            conv_offset_16_raw: None,
            conv_offset_8_raw: None,
            corr: Vec::new(),
            delta_flow: Vec::new(),
            up_mask: Vec::new(),
            net: Vec::new(),
        }
    }
}

fn pool<B: Backend>(x: Tensor<B, 4>, k: usize) -> Tensor<B, 4> {
    avg_pool2d(x, [k, k], [k, k], [0, 0], true, false)
}

/// `-scale · resize(flow, size)` with `scale = size_h / flow_h` (the reference hand-over).
fn hand_over<B: Backend>(flow: Tensor<B, 4>, size: [usize; 2]) -> Tensor<B, 4> {
    let scale = size[0] as f64 / flow.dims()[2] as f64;
    resize_bilinear_align_corners(flow, size).mul_scalar(-scale)
}

impl<B: Backend> CREStereo<B> {
    fn offsets(&self, raw: Tensor<B, 4>) -> Tensor<B, 4> {
        sigmoid(raw)
            .sub_scalar(0.5)
            .mul_scalar(2.0 * self.offset_range)
    }

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
        self.forward_traced(left, right, iters, flow_init, None)
    }

    /// [`Self::forward`] that also records intermediates into `trace`.
    pub fn forward_traced(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        iters: usize,
        flow_init: Option<Tensor<B, 4>>,
        mut trace: Option<&mut Trace<B>>,
    ) -> Vec<Tensor<B, 4>> {
        let [n, ch, h, w] = left.dims();
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
        let hd = self.hidden_dim;
        let rate = self.upsample_rate;
        let norm = |x: Tensor<B, 4>| x.div_scalar(255.0).mul_scalar(2.0).sub_scalar(1.0);
        let (fmap1, fmap2) = self.fnet.forward_pair(norm(left), norm(right));
        let [_, c, h4, w4] = fmap1.dims();
        if let Some(t) = trace.as_deref_mut() {
            t.fmap1 = Some(fmap1.clone());
            t.fmap2 = Some(fmap2.clone());
        }

        // 1/8 features and offsets
        let fmap1_dw8 = pool(fmap1.clone(), 2);
        let fmap2_dw8 = pool(fmap2.clone(), 2);
        let offset_dw8_raw = self.conv_offset_8.forward(fmap1_dw8.clone());
        let offset_dw8 = self.offsets(offset_dw8_raw.clone());

        // context: hidden state and input
        let net = tanh(fmap1.clone().slice([0..n, 0..hd, 0..h4, 0..w4]));
        let inp = relu(fmap1.clone().slice([0..n, hd..c, 0..h4, 0..w4]));
        let net_dw8 = pool(net.clone(), 2);
        let inp_dw8 = pool(inp.clone(), 2);

        // 1/16 features, offsets, positional encoding and self-attention
        let fmap1_dw16 = pool(fmap1.clone(), 4);
        let fmap2_dw16 = pool(fmap2.clone(), 4);
        let offset_dw16_raw = self.conv_offset_16.forward(fmap1_dw16.clone());
        let offset_dw16 = self.offsets(offset_dw16_raw.clone());
        let net_dw16 = pool(net.clone(), 4);
        let inp_dw16 = pool(inp.clone(), 4);
        let [_, _, h16, w16] = fmap1_dw16.dims();
        let (sa_left, sa_right) = self.self_att_fn.forward_self(
            to_tokens(self.pos_encoding.forward(fmap1_dw16)),
            to_tokens(self.pos_encoding.forward(fmap2_dw16)),
        );
        if let Some(t) = trace.as_deref_mut() {
            t.pos_encoding = Some(Tensor::from_data(
                TensorData::new(self.pos_encoding.table(h16, w16), [c, h16, w16]),
                &fmap1.device(),
            ));
            t.selfatt_left_tokens = Some(sa_left.clone());
            t.selfatt_right_tokens = Some(sa_right.clone());
            t.conv_offset_16_raw = Some(offset_dw16_raw.clone());
            t.conv_offset_8_raw = Some(offset_dw8_raw.clone());
        }
        let fmap1_dw16 = from_tokens(sa_left, h16, w16);
        let fmap2_dw16 = from_tokens(sa_right, h16, w16);

        let agcl = AdaptiveGroupCorrelationConfig::new().with_groups(self.groups);
        let corr_fn = agcl.init(fmap1.clone(), fmap2.clone());
        let corr_fn_dw8 = agcl.init(fmap1_dw8, fmap2_dw8);
        let corr_fn_att_dw16 = agcl.init(fmap1_dw16, fmap2_dw16);

        let mut predictions = Vec::new();
        let mut net = net;
        let mut flow: Tensor<B, 4>;
        match flow_init {
            Some(init) => {
                flow = hand_over(init, [h4, w4]);
            }
            None => {
                // RUM 1/16
                let mut flow_dw16 = Tensor::<B, 4>::zeros([n, 2, h16, w16], &fmap1.device());
                let mut net_dw16 = net_dw16;
                flow = Tensor::zeros([n, 2, h16 * rate, w16 * rate], &fmap1.device());
                for itr in 0..iters / 2 {
                    let window = SearchWindow::for_iteration(itr);
                    flow_dw16 = flow_dw16.detach();
                    let (l, r) = corr_fn_att_dw16.cross_attend(&self.cross_att_fn);
                    if let Some(t) = trace.as_deref_mut()
                        && t.crossatt_left_tokens_call0.is_none()
                    {
                        t.crossatt_left_tokens_call0 = Some(l.clone());
                        t.crossatt_right_tokens_call0 = Some(r.clone());
                    }
                    let corr = corr_fn_att_dw16.corr_offset_maps(
                        from_tokens(l, h16, w16),
                        from_tokens(r, h16, w16),
                        flow_dw16.clone(),
                        offset_dw16.clone(),
                        window,
                    );
                    let (net_new, up_mask, delta_flow) = self.update_block.forward(
                        net_dw16,
                        inp_dw16.clone(),
                        corr.clone(),
                        flow_dw16.clone(),
                    );
                    net_dw16 = net_new;
                    record(&mut trace, corr, &delta_flow, &up_mask, &net_dw16);
                    flow_dw16 = flow_dw16 + delta_flow;
                    flow = convex_upsample(flow_dw16.clone(), up_mask, rate);
                    let [_, _, fh, fw] = flow.dims();
                    predictions.push(
                        resize_bilinear_align_corners(flow.clone(), [4 * fh, 4 * fw])
                            .mul_scalar(-4.0),
                    );
                }
                // RUM 1/8
                let [_, _, h8, w8] = corr_fn_dw8.fmap1.dims();
                let mut flow_dw8 = hand_over(flow.clone(), [h8, w8]);
                let mut net_dw8 = net_dw8;
                for itr in 0..iters / 2 {
                    let window = SearchWindow::for_iteration(itr);
                    flow_dw8 = flow_dw8.detach();
                    let corr =
                        corr_fn_dw8.corr_offset(flow_dw8.clone(), offset_dw8.clone(), window, None);
                    let (net_new, up_mask, delta_flow) = self.update_block.forward(
                        net_dw8,
                        inp_dw8.clone(),
                        corr.clone(),
                        flow_dw8.clone(),
                    );
                    net_dw8 = net_new;
                    record(&mut trace, corr, &delta_flow, &up_mask, &net_dw8);
                    flow_dw8 = flow_dw8 + delta_flow;
                    flow = convex_upsample(flow_dw8.clone(), up_mask, rate);
                    let [_, _, fh, fw] = flow.dims();
                    predictions.push(
                        resize_bilinear_align_corners(flow.clone(), [2 * fh, 2 * fw])
                            .mul_scalar(-2.0),
                    );
                }
                if iters / 2 == 0 {
                    flow = Tensor::zeros([n, 2, h8 * rate, w8 * rate], &fmap1.device());
                }
                flow = hand_over(flow, [h4, w4]);
            }
        }

        // RUM 1/4
        for itr in 0..iters {
            let window = SearchWindow::for_iteration(itr);
            flow = flow.detach();
            let corr = corr_fn.corr_warp(flow.clone(), window);
            let (net_new, up_mask, delta_flow) =
                self.update_block
                    .forward(net, inp.clone(), corr.clone(), flow.clone());
            net = net_new;
            record(&mut trace, corr, &delta_flow, &up_mask, &net);
            flow = flow + delta_flow;
            predictions.push(convex_upsample(flow.clone(), up_mask, rate).neg());
        }
        predictions
    }
}

fn record<B: Backend>(
    trace: &mut Option<&mut Trace<B>>,
    corr: Tensor<B, 4>,
    delta_flow: &Tensor<B, 4>,
    up_mask: &Tensor<B, 4>,
    net: &Tensor<B, 4>,
) {
    if let Some(t) = trace.as_deref_mut() {
        t.corr.push(corr);
        t.delta_flow.push(delta_flow.clone());
        t.up_mask.push(up_mask.clone());
        t.net.push(net.clone());
    }
}
