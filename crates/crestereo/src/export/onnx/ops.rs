//! The ops of [`Graph`]: each appends its node and works out its output's static shape, checking
//! its operands as Burn would.

use super::graph::{Attr, Graph, Value, broadcast};

impl Graph {
    // ---- element-wise ----

    pub fn unary(&mut self, op_type: &str, x: &Value) -> Value {
        self.op(op_type, &[x], vec![], x.shape.clone())
    }

    pub fn binary(&mut self, op_type: &str, a: &Value, b: &Value) -> Value {
        let shape = broadcast(&a.shape, &b.shape);
        self.op(op_type, &[a, b], vec![], shape)
    }

    pub fn add(&mut self, a: &Value, b: &Value) -> Value {
        self.binary("Add", a, b)
    }

    pub fn sub(&mut self, a: &Value, b: &Value) -> Value {
        self.binary("Sub", a, b)
    }

    pub fn mul(&mut self, a: &Value, b: &Value) -> Value {
        self.binary("Mul", a, b)
    }

    pub fn div(&mut self, a: &Value, b: &Value) -> Value {
        self.binary("Div", a, b)
    }

    /// `op_type` of `x` and the constant `v`.
    fn binary_scalar(&mut self, op_type: &str, x: &Value, v: f32) -> Value {
        let s = self.scalar(v);
        self.binary(op_type, x, &s)
    }

    pub fn add_scalar(&mut self, x: &Value, v: f32) -> Value {
        self.binary_scalar("Add", x, v)
    }

    pub fn sub_scalar(&mut self, x: &Value, v: f32) -> Value {
        self.binary_scalar("Sub", x, v)
    }

    pub fn mul_scalar(&mut self, x: &Value, v: f32) -> Value {
        self.binary_scalar("Mul", x, v)
    }

    pub fn div_scalar(&mut self, x: &Value, v: f32) -> Value {
        self.binary_scalar("Div", x, v)
    }

    pub fn relu(&mut self, x: &Value) -> Value {
        self.unary("Relu", x)
    }

    pub fn sigmoid(&mut self, x: &Value) -> Value {
        self.unary("Sigmoid", x)
    }

    pub fn tanh(&mut self, x: &Value) -> Value {
        self.unary("Tanh", x)
    }

    pub fn neg(&mut self, x: &Value) -> Value {
        self.unary("Neg", x)
    }

    // ---- shapes ----

    pub fn reshape(&mut self, x: &Value, shape: &[usize]) -> Value {
        assert_eq!(
            x.numel(),
            shape.iter().product::<usize>(),
            "reshape {:?} to {shape:?}",
            x.shape
        );
        if x.shape == shape {
            return x.clone();
        }
        let dims: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
        let target = self.ints("shape", &dims);
        self.op_named(
            "Reshape",
            vec![x.name.clone(), target],
            vec![],
            shape.to_vec(),
        )
    }

    pub fn transpose(&mut self, x: &Value, perm: &[usize]) -> Value {
        assert_eq!(perm.len(), x.shape.len(), "transpose: permutation rank");
        let shape = perm.iter().map(|&p| x.shape[p]).collect();
        let perm = perm.iter().map(|&p| p as i64).collect();
        self.op("Transpose", &[x], vec![("perm", Attr::Ints(perm))], shape)
    }

    pub fn concat(&mut self, parts: &[&Value], axis: usize) -> Value {
        let mut shape = parts[0].shape.clone();
        shape[axis] = 0;
        for p in parts {
            assert_eq!(p.shape.len(), shape.len(), "concat: ranks differ");
            for (i, (&a, &b)) in p.shape.iter().zip(&parts[0].shape).enumerate() {
                assert!(
                    i == axis || a == b,
                    "concat: {:?} vs {:?}",
                    p.shape,
                    parts[0].shape
                );
            }
            shape[axis] += p.shape[axis];
        }
        self.op(
            "Concat",
            parts,
            vec![("axis", Attr::Int(axis as i64))],
            shape,
        )
    }

    /// `x.narrow(axis, start, len)`.
    pub fn narrow(&mut self, x: &Value, axis: usize, start: usize, len: usize) -> Value {
        assert!(
            start + len <= x.shape[axis],
            "narrow past the end of {:?}",
            x.shape
        );
        if start == 0 && len == x.shape[axis] {
            return x.clone();
        }
        let starts = self.ints("starts", &[start as i64]);
        let ends = self.ints("ends", &[(start + len) as i64]);
        let axes = self.ints("axes", &[axis as i64]);
        let mut shape = x.shape.clone();
        shape[axis] = len;
        self.op_named(
            "Slice",
            vec![x.name.clone(), starts, ends, axes],
            vec![],
            shape,
        )
    }

    /// `x[.., lo_h..hi_h, lo_w..hi_w]` of an (N, C, H, W) value.
    pub fn crop(
        &mut self,
        x: &Value,
        rows: std::ops::Range<usize>,
        cols: std::ops::Range<usize>,
    ) -> Value {
        let y = self.narrow(x, 2, rows.start, rows.len());
        self.narrow(&y, 3, cols.start, cols.len())
    }

    // ---- reductions ----

    /// Mean over `axis`, kept as size 1.
    pub fn mean_dim(&mut self, x: &Value, axis: usize) -> Value {
        let mut shape = x.shape.clone();
        shape[axis] = 1;
        self.op(
            "ReduceMean",
            &[x],
            vec![
                ("axes", Attr::Ints(vec![axis as i64])),
                ("keepdims", Attr::Int(1)),
            ],
            shape,
        )
    }

    /// Sum over `axis`, kept as size 1 (ReduceSum takes its axes as an input since opset 13).
    pub fn sum_dim(&mut self, x: &Value, axis: usize) -> Value {
        let mut shape = x.shape.clone();
        shape[axis] = 1;
        let axes = self.ints("axes", &[axis as i64]);
        self.op_named(
            "ReduceSum",
            vec![x.name.clone(), axes],
            vec![("keepdims", Attr::Int(1))],
            shape,
        )
    }

    pub fn softmax(&mut self, x: &Value, axis: usize) -> Value {
        self.op(
            "Softmax",
            &[x],
            vec![("axis", Attr::Int(axis as i64))],
            x.shape.clone(),
        )
    }

    // ---- linear algebra, convolution, sampling ----

    /// Batched matrix product with NumPy broadcasting of the leading axes.
    pub fn matmul(&mut self, a: &Value, b: &Value) -> Value {
        let (ra, rb) = (a.shape.len(), b.shape.len());
        assert!(ra >= 2 && rb >= 2, "matmul needs rank ≥ 2");
        assert_eq!(
            a.shape[ra - 1],
            b.shape[rb - 2],
            "matmul {:?} @ {:?}",
            a.shape,
            b.shape
        );
        let mut shape = broadcast(&a.shape[..ra - 2], &b.shape[..rb - 2]);
        shape.extend([a.shape[ra - 2], b.shape[rb - 1]]);
        self.op("MatMul", &[a, b], vec![], shape)
    }

    /// A 2-D convolution; `pads` = [top, left, bottom, right].
    #[allow(clippy::too_many_arguments)]
    pub fn conv(
        &mut self,
        x: &Value,
        weight: &Value,
        bias: Option<&Value>,
        stride: [usize; 2],
        pads: [usize; 4],
        dilation: [usize; 2],
        groups: usize,
    ) -> Value {
        let [n, c, h, w] = x.dims();
        let [co, ci, kh, kw] = weight.dims();
        assert_eq!(c, ci * groups, "conv: input channels");
        let out = |size: usize, pad: usize, k: usize, d: usize, s: usize| {
            (size + pad - d * (k - 1) - 1) / s + 1
        };
        let ho = out(h, pads[0] + pads[2], kh, dilation[0], stride[0]);
        let wo = out(w, pads[1] + pads[3], kw, dilation[1], stride[1]);
        let mut inputs = vec![x, weight];
        inputs.extend(bias);
        let i64s = |v: &[usize]| Attr::Ints(v.iter().map(|&d| d as i64).collect());
        self.op(
            "Conv",
            &inputs,
            vec![
                ("kernel_shape", i64s(&[kh, kw])),
                ("strides", i64s(&stride)),
                ("pads", i64s(&pads)),
                ("dilations", i64s(&dilation)),
                ("group", Attr::Int(groups as i64)),
            ],
            vec![n, co, ho, wo],
        )
    }

    /// `k`×`k` average pooling with stride `k`, no padding.
    pub fn avg_pool(&mut self, x: &Value, k: usize) -> Value {
        let [n, c, h, w] = x.dims();
        self.op(
            "AveragePool",
            &[x],
            vec![
                ("kernel_shape", Attr::Ints(vec![k as i64; 2])),
                ("strides", Attr::Ints(vec![k as i64; 2])),
            ],
            vec![n, c, h / k, w / k],
        )
    }

    /// `img` (N, C, H, W) sampled bilinearly at `grid` (N, Ho, Wo, 2) of coordinates normalised
    /// with align_corners (−1 and 1 are the centres of the border pixels), zeros outside.
    pub fn grid_sample(&mut self, img: &Value, grid: &Value) -> Value {
        let [n, c, _, _] = img.dims();
        let [gn, ho, wo, two] = grid.dims();
        assert!(gn == n && two == 2, "grid_sample: grid {:?}", grid.shape);
        self.op(
            "GridSample",
            &[img, grid],
            vec![
                ("align_corners", Attr::Int(1)),
                ("mode", Attr::Str("bilinear")),
                ("padding_mode", Attr::Str("zeros")),
            ],
            vec![n, c, ho, wo],
        )
    }

    /// PyTorch's `InstanceNorm2d` without affine parameters, in the order of operations of
    /// [`crate::network::encoder::instance_norm`] (biased variance over H×W).
    pub fn instance_norm(&mut self, x: &Value, eps: f64) -> Value {
        let [n, c, h, w] = x.dims();
        let flat = self.reshape(x, &[n, c, h * w]);
        let mean = self.mean_dim(&flat, 2);
        let centered = self.sub(&flat, &mean);
        let square = self.mul(&centered, &centered);
        let var = self.mean_dim(&square, 2);
        let var = self.add_scalar(&var, eps as f32);
        let std = self.unary("Sqrt", &var);
        let y = self.div(&centered, &std);
        self.reshape(&y, &[n, c, h, w])
    }

    /// LayerNormalization over the last axis.
    pub fn layer_norm(&mut self, x: &Value, gamma: &Value, beta: &Value, eps: f64) -> Value {
        self.op(
            "LayerNormalization",
            &[x, gamma, beta],
            vec![
                ("axis", Attr::Int(-1)),
                ("epsilon", Attr::Float(eps as f32)),
            ],
            x.shape.clone(),
        )
    }
}
