//! A static-shape ONNX graph under construction: every value carries its shape, so the module
//! emitters read shapes the way their `forward` reads `dims()`, and every op checks its
//! operands the way Burn would.

use std::collections::{BTreeSet, HashMap};

use burn::module::{Param, ParamId};
use burn::prelude::*;
use onnx_protobuf::attribute_proto::AttributeType;
use onnx_protobuf::tensor_proto::DataType;
use onnx_protobuf::tensor_shape_proto::{Dimension, dimension};
use onnx_protobuf::type_proto;
use onnx_protobuf::{
    AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, TensorProto,
    TensorShapeProto, TypeProto, ValueInfoProto,
};

/// The opset the graph is written for: LayerNormalization (17) and GridSample (16) exist there,
/// and ReduceMean still takes its axes as an attribute.
pub const OPSET: i64 = 17;
/// The IR version that goes with opset 17 (ONNX 1.12).
pub const IR_VERSION: i64 = 8;

/// A float32 value of the graph: its name and static shape.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Value {
    pub name: String,
    pub shape: Vec<usize>,
}

impl Value {
    pub fn dims<const D: usize>(&self) -> [usize; D] {
        self.shape
            .as_slice()
            .try_into()
            .unwrap_or_else(|_| panic!("{} has rank {}, not {D}", self.name, self.shape.len()))
    }

    fn numel(&self) -> usize {
        self.shape.iter().product()
    }
}

/// An attribute of a node.
pub enum Attr {
    Int(i64),
    Ints(Vec<i64>),
    Float(f32),
    Str(&'static str),
}

fn attribute(name: &str, value: Attr) -> AttributeProto {
    let mut a = AttributeProto {
        name: name.into(),
        ..Default::default()
    };
    let kind = match value {
        Attr::Int(i) => {
            a.i = i;
            AttributeType::INT
        }
        Attr::Ints(v) => {
            a.ints = v;
            AttributeType::INTS
        }
        Attr::Float(f) => {
            a.f = f;
            AttributeType::FLOAT
        }
        Attr::Str(s) => {
            a.s = s.as_bytes().to_vec();
            AttributeType::STRING
        }
    };
    a.type_ = kind.into();
    a
}

fn value_info(v: &Value) -> ValueInfoProto {
    let shape = TensorShapeProto {
        dim: v
            .shape
            .iter()
            .map(|&d| Dimension {
                value: Some(dimension::Value::DimValue(d as i64)),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    };
    let tensor = type_proto::Tensor {
        elem_type: DataType::FLOAT as i32,
        shape: Some(shape).into(),
        ..Default::default()
    };
    ValueInfoProto {
        name: v.name.clone(),
        type_: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(tensor)),
            ..Default::default()
        })
        .into(),
        ..Default::default()
    }
}

/// NumPy broadcasting of two shapes.
fn broadcast(a: &[usize], b: &[usize]) -> Vec<usize> {
    let rank = a.len().max(b.len());
    let at = |s: &[usize], i: usize| (i + s.len()).checked_sub(rank).map_or(1, |j| s[j]);
    (0..rank)
        .map(|i| match (at(a, i), at(b, i)) {
            (x, y) if x == y => x,
            (1, y) => y,
            (x, 1) => x,
            (x, y) => panic!("cannot broadcast {a:?} with {b:?} (axis {i}: {x} vs {y})"),
        })
        .collect()
}

/// The graph being built.
#[derive(Default)]
pub struct Graph {
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
    inputs: Vec<Value>,
    outputs: Vec<Value>,
    params: HashMap<ParamId, Value>,
    next: usize,
}

impl Graph {
    fn fresh(&mut self, hint: &str) -> String {
        self.next += 1;
        format!("{hint}_{}", self.next)
    }

    /// A graph input (float32, static shape).
    pub fn input(&mut self, name: &str, shape: &[usize]) -> Value {
        let v = Value {
            name: name.into(),
            shape: shape.to_vec(),
        };
        self.inputs.push(v.clone());
        v
    }

    /// Names `v` as a graph output.
    pub fn output(&mut self, v: &Value, name: &str) {
        self.nodes.push(NodeProto {
            input: vec![v.name.clone()],
            output: vec![name.into()],
            name: format!("output_{name}"),
            op_type: "Identity".into(),
            ..Default::default()
        });
        self.outputs.push(Value {
            name: name.into(),
            shape: v.shape.clone(),
        });
    }

    /// A float32 initializer.
    pub fn constant(&mut self, hint: &str, data: &[f32], shape: &[usize]) -> Value {
        assert_eq!(
            data.len(),
            shape.iter().product::<usize>(),
            "{hint}: data/shape"
        );
        let name = self.fresh(hint);
        self.initializers.push(TensorProto {
            name: name.clone(),
            dims: shape.iter().map(|&d| d as i64).collect(),
            data_type: DataType::FLOAT as i32,
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            ..Default::default()
        });
        Value {
            name,
            shape: shape.to_vec(),
        }
    }

    /// A scalar float32 constant (shape `[]`, broadcast by the element-wise ops).
    pub fn scalar(&mut self, v: f32) -> Value {
        self.constant("scalar", &[v], &[])
    }

    /// An int64 initializer (shapes, axes, slice bounds); returns its name.
    fn ints(&mut self, hint: &str, data: &[i64]) -> String {
        let name = self.fresh(hint);
        self.initializers.push(TensorProto {
            name: name.clone(),
            dims: vec![data.len() as i64],
            data_type: DataType::INT64 as i32,
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            ..Default::default()
        });
        name
    }

    /// A module parameter as an initializer, written once however often it is used.
    pub fn param<B: Backend, const D: usize>(&mut self, p: &Param<Tensor<B, D>>) -> Value {
        if let Some(v) = self.params.get(&p.id) {
            return v.clone();
        }
        let t = p.val();
        let shape = t.dims().to_vec();
        let data: Vec<f32> = t
            .into_data()
            .convert::<f32>()
            .into_vec()
            .expect("float32 parameter data");
        let v = self.constant("param", &data, &shape);
        self.params.insert(p.id, v.clone());
        v
    }

    /// Appends a node with one output of `shape`.
    pub fn op(
        &mut self,
        op_type: &str,
        inputs: &[&Value],
        attrs: Vec<(&str, Attr)>,
        shape: Vec<usize>,
    ) -> Value {
        let names = inputs.iter().map(|v| v.name.clone()).collect();
        self.op_named(op_type, names, attrs, shape)
    }

    fn op_named(
        &mut self,
        op_type: &str,
        inputs: Vec<String>,
        attrs: Vec<(&str, Attr)>,
        shape: Vec<usize>,
    ) -> Value {
        let out = self.fresh(&op_type.to_lowercase());
        self.nodes.push(NodeProto {
            input: inputs,
            output: vec![out.clone()],
            name: format!("n{}_{op_type}", self.nodes.len()),
            op_type: op_type.into(),
            attribute: attrs.into_iter().map(|(n, a)| attribute(n, a)).collect(),
            ..Default::default()
        });
        Value { name: out, shape }
    }

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

    pub fn add_scalar(&mut self, x: &Value, v: f32) -> Value {
        let s = self.scalar(v);
        self.add(x, &s)
    }

    pub fn sub_scalar(&mut self, x: &Value, v: f32) -> Value {
        let s = self.scalar(v);
        self.sub(x, &s)
    }

    pub fn mul_scalar(&mut self, x: &Value, v: f32) -> Value {
        let s = self.scalar(v);
        self.mul(x, &s)
    }

    pub fn div_scalar(&mut self, x: &Value, v: f32) -> Value {
        let s = self.scalar(v);
        self.div(x, &s)
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
    /// [`crate::encoder::instance_norm`] (biased variance over H×W).
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

    // ---- the result ----

    /// Op types used, sorted.
    pub fn op_types(&self) -> BTreeSet<String> {
        self.nodes.iter().map(|n| n.op_type.clone()).collect()
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// The model: one graph, opset 17 of the default domain.
    pub fn into_model(self, name: &str, doc: &str) -> ModelProto {
        let graph = GraphProto {
            name: name.into(),
            node: self.nodes,
            initializer: self.initializers,
            input: self.inputs.iter().map(value_info).collect(),
            output: self.outputs.iter().map(value_info).collect(),
            ..Default::default()
        };
        ModelProto {
            ir_version: IR_VERSION,
            opset_import: vec![OperatorSetIdProto {
                domain: String::new(),
                version: OPSET,
                ..Default::default()
            }],
            producer_name: "crestereo".into(),
            producer_version: env!("CARGO_PKG_VERSION").into(),
            doc_string: doc.into(),
            graph: Some(graph).into(),
            ..Default::default()
        }
    }
}
