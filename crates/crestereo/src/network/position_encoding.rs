//! LoFTR's 2D sine positional encoding, including the quirk of the released LoFTR code that
//! CREStereo inherits: the frequency term is `exp(-2k)` (an operator-precedence slip in
//! `-log(10000) / d_model // 2`), and positions start at 1.

use burn::prelude::*;

#[derive(Config, Debug)]
pub struct PositionEncodingSineConfig {
    #[config(default = 256)]
    pub d_model: usize,
    /// `false` reproduces the reference (buggy) frequencies; `true` uses the intended
    /// `exp(-2k·ln(10000)/(d_model/2))`.
    #[config(default = false)]
    pub temp_bug_fix: bool,
}

/// Parameter-free module; the table is computed for the requested size on the fly.
#[derive(Module, Clone, Debug)]
pub struct PositionEncodingSine {
    pub d_model: usize,
    pub temp_bug_fix: bool,
}

impl PositionEncodingSineConfig {
    pub fn init(&self) -> PositionEncodingSine {
        assert!(
            self.d_model.is_multiple_of(4),
            "d_model must be a multiple of 4"
        );
        PositionEncodingSine {
            d_model: self.d_model,
            temp_bug_fix: self.temp_bug_fix,
        }
    }
}

impl PositionEncodingSine {
    /// The `(d_model, h, w)` table, computed in float32 like the reference.
    pub fn table(&self, h: usize, w: usize) -> Vec<f32> {
        let d = self.d_model;
        let mut pe = vec![0f32; d * h * w];
        for k in 0..d / 4 {
            let two_k = (2 * k) as f32;
            let div: f32 = if self.temp_bug_fix {
                (two_k * (-(10000f32).ln() / (d / 2) as f32)).exp()
            } else {
                // (-ln(10000) / d_model) // 2 == -1.0 for any d_model > 9.2
                (-two_k).exp()
            };
            for i in 0..h {
                let y = (i + 1) as f32 * div;
                for j in 0..w {
                    let x = (j + 1) as f32 * div;
                    let at = |c: usize| c * h * w + i * w + j;
                    pe[at(4 * k)] = x.sin();
                    pe[at(4 * k + 1)] = x.cos();
                    pe[at(4 * k + 2)] = y.sin();
                    pe[at(4 * k + 3)] = y.cos();
                }
            }
        }
        pe
    }

    /// The table as a tensor (d_model, h, w).
    pub fn table_tensor<B: Backend>(&self, h: usize, w: usize, device: &B::Device) -> Tensor<B, 3> {
        Tensor::from_data(
            TensorData::new(self.table(h, w), [self.d_model, h, w]),
            device,
        )
    }

    /// `x + table` for `x` of shape (N, d_model, H, W) and its `table` (d_model, H, W).
    pub fn add<B: Backend>(&self, x: Tensor<B, 4>, table: &Tensor<B, 3>) -> Tensor<B, 4> {
        let [_, c, h, w] = x.dims();
        assert_eq!(
            [c, h, w],
            [self.d_model, table.dims()[1], table.dims()[2]],
            "positional encoding: shape mismatch"
        );
        x + table.clone().unsqueeze::<4>()
    }

    /// `x + pe` for `x` of shape (N, d_model, H, W).
    pub fn forward<B: Backend>(&self, x: Tensor<B, 4>) -> Tensor<B, 4> {
        let [_, _, h, w] = x.dims();
        let table = self.table_tensor(h, w, &x.device());
        self.add(x, &table)
    }
}

impl PositionEncodingSine {
    /// [`Self::forward`] as ONNX nodes: the table is a constant of the graph.
    pub fn emit(
        &self,
        g: &mut crate::export::onnx::Graph,
        x: &crate::export::onnx::Value,
    ) -> crate::export::onnx::Value {
        let [_, c, h, w] = x.dims();
        assert_eq!(c, self.d_model, "positional encoding: shape mismatch");
        let table = g.shared_constant("position_encoding", &[1, c, h, w], || self.table(h, w));
        g.add(x, &table)
    }
}

#[cfg(test)]
mod tests {

    use super::*;
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    use crate::test_util::uniform;

    /// The table as a graph constant plus the map, against `forward`.
    #[test]
    fn emitted_encoding_matches_forward() {
        let pe = PositionEncodingSineConfig::new().with_d_model(16).init();
        let x = uniform([2, 16, 5, 7], -1.0, 1.0);
        let out = run_emitted(&[x.to_data()], |g, v| vec![pe.emit(g, &v[0])]);
        assert_emit_matches(
            "position encoding",
            &out[0],
            pe.forward(x).into_data(),
            1e-6,
        );
    }
}
