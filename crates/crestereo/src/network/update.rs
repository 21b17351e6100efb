//! Recurrent update block: motion encoder → SepConvGRU → flow head (Δflow) and mask head
//! (convex-upsampling weights, scaled by 0.25).

use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::export::onnx::{Graph, Value};
use crate::network::encoder::conv_cfg;
use crate::network::gru::{SepConvGru, SepConvGruConfig};
use crate::network::motion_encoder::{BasicMotionEncoder, BasicMotionEncoderConfig};
use crate::ops::conv2d::Conv2d;

#[derive(Config, Debug)]
pub struct FlowHeadConfig {
    #[config(default = 128)]
    pub input_dim: usize,
    #[config(default = 256)]
    pub hidden_dim: usize,
}

#[derive(Module, Debug)]
pub struct FlowHead<B: Backend> {
    pub conv1: Conv2d<B>,
    pub conv2: Conv2d<B>,
}

impl FlowHeadConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> FlowHead<B> {
        FlowHead {
            conv1: conv_cfg(self.input_dim, self.hidden_dim, [3, 3], 1, [1, 1]).init(device),
            conv2: conv_cfg(self.hidden_dim, 2, [3, 3], 1, [1, 1]).init(device),
        }
    }
}

impl<B: Backend> FlowHead<B> {
    pub fn forward(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        self.conv2.forward(relu(self.conv1.forward(x)))
    }
}

#[derive(Config, Debug)]
pub struct UpdateBlockConfig {
    #[config(default = 128)]
    pub hidden_dim: usize,
    #[config(default = 36)]
    pub cor_planes: usize,
    /// Convex upsampling factor (4): the mask head outputs 9·4·4 = 144 channels.
    #[config(default = 4)]
    pub mask_size: usize,
}

/// Parameter names follow the reference; `mask.0` / `mask.2` are imported as `mask1` / `mask2`.
#[derive(Module, Debug)]
pub struct UpdateBlock<B: Backend> {
    pub encoder: BasicMotionEncoder<B>,
    pub gru: SepConvGru<B>,
    pub flow_head: FlowHead<B>,
    pub mask1: Conv2d<B>,
    pub mask2: Conv2d<B>,
}

impl UpdateBlockConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> UpdateBlock<B> {
        let h = self.hidden_dim;
        UpdateBlock {
            encoder: BasicMotionEncoderConfig::new()
                .with_cor_planes(self.cor_planes)
                .init(device),
            gru: SepConvGruConfig::new()
                .with_hidden_dim(h)
                .with_input_dim(128 + h)
                .init(device),
            flow_head: FlowHeadConfig::new().with_input_dim(h).init(device),
            mask1: conv_cfg(h, 256, [3, 3], 1, [1, 1]).init(device),
            mask2: conv_cfg(256, self.mask_size * self.mask_size * 9, [1, 1], 1, [0, 0])
                .init(device),
        }
    }
}

impl<B: Backend> UpdateBlock<B> {
    /// Returns (new hidden state, up-mask, Δflow).
    pub fn forward(
        &self,
        net: Tensor<B, 4>,
        inp: Tensor<B, 4>,
        corr: Tensor<B, 4>,
        flow: Tensor<B, 4>,
    ) -> (Tensor<B, 4>, Tensor<B, 4>, Tensor<B, 4>) {
        let motion = self.encoder.forward(flow, corr);
        let inp = crate::ops::channels::cat_channels(inp, motion);
        let net = self.gru.forward(net, inp);
        let delta_flow = self.flow_head.forward(net.clone());
        let mask = (self.mask2.forward(relu(self.mask1.forward(net.clone())))).mul_scalar(0.25);
        (net, mask, delta_flow)
    }
}

impl<B: Backend> FlowHead<B> {
    /// [`Self::forward`] as ONNX nodes.
    pub fn emit(&self, g: &mut Graph, x: &Value) -> Value {
        let y = self.conv1.emit(g, x);
        let y = g.relu(&y);
        self.conv2.emit(g, &y)
    }
}

impl<B: Backend> UpdateBlock<B> {
    /// [`Self::forward`] as ONNX nodes: (new hidden state, up-mask, Δflow). The mask head is
    /// emitted only when `with_mask` (a graph needs the mask of a level's last iteration only).
    pub fn emit(
        &self,
        g: &mut Graph,
        net: &Value,
        inp: &Value,
        corr: &Value,
        flow: &Value,
        with_mask: bool,
    ) -> (Value, Option<Value>, Value) {
        let motion = self.encoder.emit(g, flow, corr);
        let inp = g.concat(&[inp, &motion], 1);
        let net = self.gru.emit(g, net, &inp);
        let delta_flow = self.flow_head.emit(g, &net);
        let mask = with_mask.then(|| {
            let m = self.mask1.emit(g, &net);
            let m = g.relu(&m);
            let m = self.mask2.emit(g, &m);
            g.mul_scalar(&m, 0.25)
        });
        (net, mask, delta_flow)
    }
}

#[cfg(test)]
mod tests {

    use super::*;
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    use crate::test_util::uniform;

    /// The update block of a level's last iteration (with the mask head) as graph nodes against
    /// `forward`: hidden state, up-mask and Δflow.
    #[test]
    fn emitted_update_block_matches_forward() {
        let block = UpdateBlockConfig::new().init::<crate::CpuBackend>(&Default::default());
        let (n, h, w) = (1, 6, 8);
        let net = uniform([n, 128, h, w], -1.0, 1.0);
        let inp = uniform([n, 128, h, w], 0.0, 1.0);
        let corr = uniform([n, 36, h, w], -1.0, 1.0);
        let flow = uniform([n, 2, h, w], -4.0, 4.0);
        let inputs = [&net, &inp, &corr, &flow].map(|t| t.to_data());
        let out = run_emitted(&inputs, |g, x| {
            let (net, mask, delta) = block.emit(g, &x[0], &x[1], &x[2], &x[3], true);
            vec![net, mask.expect("the mask head"), delta]
        });
        let (net, mask, delta) = block.forward(net, inp, corr, flow);
        assert_emit_matches("hidden state", &out[0], net.into_data(), 1e-5);
        assert_emit_matches("up-mask", &out[1], mask.into_data(), 1e-5);
        assert_emit_matches("delta flow", &out[2], delta.into_data(), 1e-5);
    }
}
