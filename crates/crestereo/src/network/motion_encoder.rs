//! Motion encoder: correlation (36 ch) and flow (2 ch) branches fused into 126 channels, with
//! the flow appended (128 channels out).

use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::network::encoder::conv_cfg;
use crate::ops::conv2d::Conv2d;

#[derive(Config, Debug)]
pub struct BasicMotionEncoderConfig {
    /// groups × search candidates = 4 × 9.
    #[config(default = 36)]
    pub cor_planes: usize,
}

#[derive(Module, Debug)]
pub struct BasicMotionEncoder<B: Backend> {
    pub convc1: Conv2d<B>,
    pub convc2: Conv2d<B>,
    pub convf1: Conv2d<B>,
    pub convf2: Conv2d<B>,
    pub conv: Conv2d<B>,
}

impl BasicMotionEncoderConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> BasicMotionEncoder<B> {
        BasicMotionEncoder {
            convc1: conv_cfg(self.cor_planes, 256, [1, 1], 1, [0, 0]).init(device),
            convc2: conv_cfg(256, 192, [3, 3], 1, [1, 1]).init(device),
            convf1: conv_cfg(2, 128, [7, 7], 1, [3, 3]).init(device),
            convf2: conv_cfg(128, 64, [3, 3], 1, [1, 1]).init(device),
            conv: conv_cfg(64 + 192, 128 - 2, [3, 3], 1, [1, 1]).init(device),
        }
    }
}

impl<B: Backend> BasicMotionEncoder<B> {
    pub fn forward(&self, flow: Tensor<B, 4>, corr: Tensor<B, 4>) -> Tensor<B, 4> {
        let cor = relu(self.convc1.forward(corr));
        let cor = relu(self.convc2.forward(cor));
        let flo = relu(self.convf1.forward(flow.clone()));
        let flo = relu(self.convf2.forward(flo));
        let out = relu(
            self.conv
                .forward(crate::ops::channels::cat(vec![cor, flo], 1)),
        );
        crate::ops::channels::cat(vec![out, flow], 1)
    }
}

impl<B: Backend> BasicMotionEncoder<B> {
    /// [`Self::forward`] as ONNX nodes.
    pub fn emit(
        &self,
        g: &mut crate::export::onnx::Graph,
        flow: &crate::export::onnx::Value,
        corr: &crate::export::onnx::Value,
    ) -> crate::export::onnx::Value {
        let cor = self.convc1.emit(g, corr);
        let cor = g.relu(&cor);
        let cor = self.convc2.emit(g, &cor);
        let cor = g.relu(&cor);
        let flo = self.convf1.emit(g, flow);
        let flo = g.relu(&flo);
        let flo = self.convf2.emit(g, &flo);
        let flo = g.relu(&flo);
        let both = g.concat(&[&cor, &flo], 1);
        let out = self.conv.emit(g, &both);
        let out = g.relu(&out);
        g.concat(&[&out, flow], 1)
    }
}

#[cfg(test)]
mod tests {

    use super::*;
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    use crate::test_util::uniform;

    #[test]
    fn emitted_motion_encoder_matches_forward() {
        let enc = BasicMotionEncoderConfig::new().init::<crate::CpuBackend>(&Default::default());
        let flow = uniform([2, 2, 6, 10], -4.0, 4.0);
        let corr = uniform([2, 36, 6, 10], -1.0, 1.0);
        let out = run_emitted(&[flow.to_data(), corr.to_data()], |g, x| {
            vec![enc.emit(g, &x[0], &x[1])]
        });
        let forward = enc.forward(flow, corr).into_data();
        assert_emit_matches("motion encoder", &out[0], forward, 1e-5);
    }
}
