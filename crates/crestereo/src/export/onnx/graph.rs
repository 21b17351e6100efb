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

    pub(super) fn numel(&self) -> usize {
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
pub(super) fn broadcast(a: &[usize], b: &[usize]) -> Vec<usize> {
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
    shared: HashMap<String, Value>,
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

    /// A float32 initializer made once per `key` and shared by every use (pixel grids, zero
    /// borders, resize matrices: the same at every iteration).
    pub fn shared_constant(
        &mut self,
        key: &str,
        shape: &[usize],
        make: impl FnOnce() -> Vec<f32>,
    ) -> Value {
        let key = format!("{key}{shape:?}");
        if let Some(v) = self.shared.get(&key) {
            return v.clone();
        }
        let hint = key.split(['[', '(']).next().unwrap_or("shared").to_string();
        let v = self.constant(&hint, &make(), shape);
        self.shared.insert(key, v.clone());
        v
    }

    /// Zeros of `shape`, one initializer per shape.
    pub fn zeros(&mut self, shape: &[usize]) -> Value {
        let n = shape.iter().product();
        self.shared_constant("zeros", shape, || vec![0.0; n])
    }

    /// A scalar float32 constant (shape `[]`, broadcast by the element-wise ops).
    pub fn scalar(&mut self, v: f32) -> Value {
        self.shared_constant(&format!("scalar_{:08x}", v.to_bits()), &[], || vec![v])
    }

    /// An int64 initializer (shapes, axes, slice bounds); returns its name.
    pub(super) fn ints(&mut self, hint: &str, data: &[i64]) -> String {
        let key = format!("{hint}{data:?}");
        if let Some(v) = self.shared.get(&key) {
            return v.name.clone();
        }
        let name = self.fresh(hint);
        self.shared.insert(
            key,
            Value {
                name: name.clone(),
                shape: vec![data.len()],
            },
        );
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

    pub(super) fn op_named(
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
