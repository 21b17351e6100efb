//! LoFTR linear attention and encoder layer (self / cross), as used by CREStereo.

use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};

use crate::ops::matmul::{linear, matmul};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::export::onnx::{Graph, Value};

#[derive(Config, Debug)]
pub struct LinearAttentionConfig {
    #[config(default = 1e-6)]
    pub eps: f64,
}

/// Linear attention (Katharopoulos et al.) with the `elu(x) + 1` feature map. No parameters.
#[derive(Module, Clone, Debug)]
pub struct LinearAttention {
    pub eps: f64,
}

impl LinearAttentionConfig {
    pub fn init(&self) -> LinearAttention {
        LinearAttention { eps: self.eps }
    }
}

fn elu_plus_one<B: Backend, const D: usize>(x: Tensor<B, D>) -> Tensor<B, D> {
    // x > 0: x + 1;  x <= 0: exp(x)
    x.clone().clamp_min(0.0) + x.clamp_max(0.0).exp()
}

impl LinearAttention {
    /// `q`: (N, L, H, D), `k`, `v`: (N, S, H, D) → (N, L, H, D).
    pub fn forward<B: Backend>(
        &self,
        q: Tensor<B, 4>,
        k: Tensor<B, 4>,
        v: Tensor<B, 4>,
    ) -> Tensor<B, 4> {
        let s = v.dims()[1] as f64;
        let q = elu_plus_one(q).permute([0, 2, 1, 3]); // n h l d
        let k = elu_plus_one(k).permute([0, 2, 1, 3]); // n h s d
        let v = v.div_scalar(s).permute([0, 2, 1, 3]); // n h s v
        let kv = matmul(k.clone().swap_dims(2, 3), v); // n h d v
        let k_sum = k.sum_dim(2).swap_dims(2, 3); // n h d 1
        let z = matmul(q.clone(), k_sum).add_scalar(self.eps).recip(); // n h l 1
        let out = matmul(q, kv).mul(z).mul_scalar(s); // n h l v
        out.permute([0, 2, 1, 3])
    }
}

#[derive(Config, Debug)]
pub struct LoFTREncoderLayerConfig {
    #[config(default = 256)]
    pub d_model: usize,
    #[config(default = 8)]
    pub nhead: usize,
    #[config(default = 1e-5)]
    pub layer_norm_eps: f64,
    #[config(default = 1e-6)]
    pub attention_eps: f64,
}

/// LoFTR encoder layer: bias-free q/k/v/merge projections, linear attention, LayerNorm,
/// an MLP on `[x, message]` (2d → 2d → d, ReLU), LayerNorm, residual.
/// Parameter names follow the reference (`mlp.0` / `mlp.2` are imported as `mlp1` / `mlp2`).
#[derive(Module, Debug)]
pub struct LoFTREncoderLayer<B: Backend> {
    pub q_proj: Linear<B>,
    pub k_proj: Linear<B>,
    pub v_proj: Linear<B>,
    pub merge: Linear<B>,
    pub mlp1: Linear<B>,
    pub mlp2: Linear<B>,
    pub norm1: LayerNorm<B>,
    pub norm2: LayerNorm<B>,
    pub attention: LinearAttention,
    pub nhead: usize,
    pub layer_norm_eps: f64,
}

impl LoFTREncoderLayerConfig {
    pub fn init<B: Backend>(&self, device: &B::Device) -> LoFTREncoderLayer<B> {
        let d = self.d_model;
        assert!(d.is_multiple_of(self.nhead));
        let lin = |i: usize, o: usize| LinearConfig::new(i, o).with_bias(false).init(device);
        let ln = || {
            LayerNormConfig::new(d)
                .with_epsilon(self.layer_norm_eps)
                .init(device)
        };
        LoFTREncoderLayer {
            q_proj: lin(d, d),
            k_proj: lin(d, d),
            v_proj: lin(d, d),
            merge: lin(d, d),
            mlp1: lin(2 * d, 2 * d),
            mlp2: lin(2 * d, d),
            norm1: ln(),
            norm2: ln(),
            attention: LinearAttentionConfig::new()
                .with_eps(self.attention_eps)
                .init(),
            nhead: self.nhead,
            layer_norm_eps: self.layer_norm_eps,
        }
    }
}

impl<B: Backend> LoFTREncoderLayer<B> {
    /// `x`: (N, L, C) queries, `source`: (N, S, C) keys/values → (N, L, C).
    pub fn forward(&self, x: Tensor<B, 3>, source: Tensor<B, 3>) -> Tensor<B, 3> {
        let [n, l, c] = x.dims();
        let s = source.dims()[1];
        let (h, d) = (self.nhead, c / self.nhead);
        let q = linear(&self.q_proj, x.clone()).reshape([n, l, h, d]);
        let k = linear(&self.k_proj, source.clone()).reshape([n, s, h, d]);
        let v = linear(&self.v_proj, source).reshape([n, s, h, d]);
        let message = self.attention.forward(q, k, v).reshape([n, l, c]);
        let message = self.norm1.forward(linear(&self.merge, message));
        let hidden = relu(linear(
            &self.mlp1,
            crate::ops::channels::cat(vec![x.clone(), message], 2),
        ));
        let message = linear(&self.mlp2, hidden);
        x + self.norm2.forward(message)
    }

    /// LoFTR "self" layer applied to both maps independently.
    pub fn forward_self(&self, a: Tensor<B, 3>, b: Tensor<B, 3>) -> (Tensor<B, 3>, Tensor<B, 3>) {
        (self.forward(a.clone(), a), self.forward(b.clone(), b))
    }

    /// LoFTR "cross" layer: `a` attends `b`, then `b` attends the updated `a`.
    pub fn forward_cross(&self, a: Tensor<B, 3>, b: Tensor<B, 3>) -> (Tensor<B, 3>, Tensor<B, 3>) {
        let a = self.forward(a, b.clone());
        let b = self.forward(b, a.clone());
        (a, b)
    }
}

/// (N, C, H, W) → (N, H·W, C), tokens row-major.
pub fn to_tokens<B: Backend>(x: Tensor<B, 4>) -> Tensor<B, 3> {
    let [n, c, h, w] = x.dims();
    x.permute([0, 2, 3, 1]).reshape([n, h * w, c])
}

/// (N, H·W, C) → (N, C, H, W).
pub fn from_tokens<B: Backend>(x: Tensor<B, 3>, h: usize, w: usize) -> Tensor<B, 4> {
    let [n, _, c] = x.dims();
    x.reshape([n, h, w, c]).permute([0, 3, 1, 2])
}

/// A bias-free or biased [`Linear`] as ONNX nodes (`x @ W (+ b)`; Burn stores W as in × out).
fn emit_linear<B: Backend>(g: &mut Graph, linear: &Linear<B>, x: &Value) -> Value {
    let w = g.param(&linear.weight);
    let y = g.matmul(x, &w);
    match &linear.bias {
        Some(b) => {
            let b = g.param(b);
            g.add(&y, &b)
        }
        None => y,
    }
}

/// [`elu_plus_one`] as ONNX nodes: `max(x, 0) + exp(min(x, 0))`.
fn emit_elu_plus_one(g: &mut Graph, x: &Value) -> Value {
    let positive = g.relu(x);
    let zero = g.scalar(0.0);
    let negative = g.binary("Min", x, &zero);
    let negative = g.unary("Exp", &negative);
    g.add(&positive, &negative)
}

impl LinearAttention {
    /// [`Self::forward`] as ONNX nodes (matrix products only: no `Einsum`).
    pub fn emit(&self, g: &mut Graph, q: &Value, k: &Value, v: &Value) -> Value {
        let s = v.shape[1] as f32;
        let q = emit_elu_plus_one(g, q);
        let q = g.transpose(&q, &[0, 2, 1, 3]);
        let k = emit_elu_plus_one(g, k);
        let k = g.transpose(&k, &[0, 2, 1, 3]);
        let v = g.div_scalar(v, s);
        let v = g.transpose(&v, &[0, 2, 1, 3]);
        let k_t = g.transpose(&k, &[0, 1, 3, 2]);
        let kv = g.matmul(&k_t, &v);
        let k_sum = g.sum_dim(&k, 2);
        let k_sum = g.transpose(&k_sum, &[0, 1, 3, 2]);
        let z = g.matmul(&q, &k_sum);
        let z = g.add_scalar(&z, self.eps as f32);
        let z = g.unary("Reciprocal", &z);
        let out = g.matmul(&q, &kv);
        let out = g.mul(&out, &z);
        let out = g.mul_scalar(&out, s);
        g.transpose(&out, &[0, 2, 1, 3])
    }
}

impl<B: Backend> LoFTREncoderLayer<B> {
    fn emit_layer_norm(&self, g: &mut Graph, norm: &LayerNorm<B>, x: &Value) -> Value {
        let gamma = g.param(&norm.gamma);
        let beta = match &norm.beta {
            Some(b) => g.param(b),
            None => {
                let d = gamma.shape[0];
                g.zeros(&[d])
            }
        };
        g.layer_norm(x, &gamma, &beta, self.layer_norm_eps)
    }

    /// [`Self::forward`] as ONNX nodes.
    pub fn emit(&self, g: &mut Graph, x: &Value, source: &Value) -> Value {
        let [n, l, c] = x.dims();
        let s = source.shape[1];
        let (h, d) = (self.nhead, c / self.nhead);
        let q = emit_linear(g, &self.q_proj, x);
        let q = g.reshape(&q, &[n, l, h, d]);
        let k = emit_linear(g, &self.k_proj, source);
        let k = g.reshape(&k, &[n, s, h, d]);
        let v = emit_linear(g, &self.v_proj, source);
        let v = g.reshape(&v, &[n, s, h, d]);
        let message = self.attention.emit(g, &q, &k, &v);
        let message = g.reshape(&message, &[n, l, c]);
        let message = emit_linear(g, &self.merge, &message);
        let message = self.emit_layer_norm(g, &self.norm1, &message);
        let hidden = g.concat(&[x, &message], 2);
        let hidden = emit_linear(g, &self.mlp1, &hidden);
        let hidden = g.relu(&hidden);
        let message = emit_linear(g, &self.mlp2, &hidden);
        let message = self.emit_layer_norm(g, &self.norm2, &message);
        g.add(x, &message)
    }

    /// [`Self::forward_self`] as ONNX nodes.
    pub fn emit_self(&self, g: &mut Graph, a: &Value, b: &Value) -> (Value, Value) {
        (self.emit(g, a, a), self.emit(g, b, b))
    }

    /// [`Self::forward_cross`] as ONNX nodes.
    pub fn emit_cross(&self, g: &mut Graph, a: &Value, b: &Value) -> (Value, Value) {
        let a = self.emit(g, a, b);
        let b = self.emit(g, b, &a);
        (a, b)
    }
}

/// [`to_tokens`] as ONNX nodes.
pub fn emit_to_tokens(g: &mut Graph, x: &Value) -> Value {
    let [n, c, h, w] = x.dims();
    let t = g.transpose(x, &[0, 2, 3, 1]);
    g.reshape(&t, &[n, h * w, c])
}

/// [`from_tokens`] as ONNX nodes.
pub fn emit_from_tokens(g: &mut Graph, x: &Value, h: usize, w: usize) -> Value {
    let [n, _, c] = x.dims();
    let t = g.reshape(x, &[n, h, w, c]);
    g.transpose(&t, &[0, 3, 1, 2])
}

#[cfg(test)]
mod tests {

    use super::*;
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    use crate::test_util::uniform;

    /// A LoFTR layer's self- and cross-attention as graph nodes (matrix products, LayerNorm)
    /// against `forward_self` / `forward_cross`, through the token reshapes both sides use.
    #[test]
    fn emitted_attention_matches_forward() {
        let layer = LoFTREncoderLayerConfig::new()
            .with_d_model(32)
            .with_nhead(4)
            .init::<crate::CpuBackend>(&Default::default());
        let (h, w) = (5, 6);
        let (a, b) = (
            uniform([2, 32, h, w], -2.0, 2.0),
            uniform([2, 32, h, w], -2.0, 2.0),
        );
        let out = run_emitted(&[a.to_data(), b.to_data()], |g, x| {
            let (ta, tb) = (emit_to_tokens(g, &x[0]), emit_to_tokens(g, &x[1]));
            let (sa, sb) = layer.emit_self(g, &ta, &tb);
            let (ca, cb) = layer.emit_cross(g, &ta, &tb);
            vec![emit_from_tokens(g, &sa, h, w), sb, ca, cb]
        });
        let (ta, tb) = (to_tokens(a), to_tokens(b));
        let (sa, sb) = layer.forward_self(ta.clone(), tb.clone());
        let (ca, cb) = layer.forward_cross(ta, tb);
        assert_emit_matches(
            "self, left",
            &out[0],
            from_tokens(sa, h, w).into_data(),
            1e-5,
        );
        assert_emit_matches("self, right", &out[1], sb.into_data(), 1e-5);
        assert_emit_matches("cross, left", &out[2], ca.into_data(), 1e-5);
        assert_emit_matches("cross, right", &out[3], cb.into_data(), 1e-5);
    }
}
