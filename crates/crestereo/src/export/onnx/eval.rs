//! A small evaluator of the graphs [`Graph`] builds, on Flex: each node run with Burn's own
//! tensor ops (Burn's convolution, pooling and grid sampling, none of this crate's kernels), in
//! the node order of the serialised model. It knows only the op types the network emits, and
//! exists so that every module's `emit` can be checked against its `forward` inside this crate,
//! module by module (`cargo test -p crestereo`), without onnxruntime.
//!
//! Values of any rank are held as rank-6 tensors with leading axes of size 1 beside their
//! logical shape; an op's axes are moved by the padding.

use std::collections::HashMap;

use burn::backend::Flex;
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid, softmax};
use burn::tensor::module::{avg_pool2d, conv2d};
use burn::tensor::ops::{
    GridSampleOptions, GridSamplePaddingMode, InterpolateMode, PaddedConvOptions,
};
use onnx_protobuf::tensor_proto::DataType;
use onnx_protobuf::{ModelProto, NodeProto, TensorProto};

use super::graph::broadcast;
use super::{Graph, Value};

/// The rank every value is held at.
const RANK: usize = 6;
type T = Tensor<Flex, RANK>;

/// A value: its logical shape and its data, padded to [`RANK`].
#[derive(Clone)]
struct Array {
    shape: Vec<usize>,
    data: T,
}

impl Array {
    fn new(shape: Vec<usize>, data: T) -> Self {
        debug_assert_eq!(padded(&shape), data.dims(), "evaluator: shape bookkeeping");
        Self { shape, data }
    }

    fn from_values(shape: &[usize], values: Vec<f32>) -> Self {
        let data = T::from_data(TensorData::new(values, padded(shape)), &Default::default());
        Self::new(shape.to_vec(), data)
    }

    /// The padded position of logical axis `axis`.
    fn axis(&self, axis: usize) -> usize {
        assert!(axis < self.shape.len(), "axis {axis} of {:?}", self.shape);
        RANK - self.shape.len() + axis
    }

    fn to_data(&self) -> TensorData {
        let values: Vec<f32> = self
            .data
            .clone()
            .into_data()
            .to_vec()
            .expect("float32 values");
        TensorData::new(values, self.shape.clone())
    }

    /// The last four axes as an NCHW tensor (the value must have rank 4).
    fn nchw(&self) -> Tensor<Flex, 4> {
        let s = self.shape.as_slice();
        assert_eq!(s.len(), 4, "evaluator: an NCHW value, got {s:?}");
        self.data.clone().reshape([s[0], s[1], s[2], s[3]])
    }

    fn from_nchw(t: Tensor<Flex, 4>) -> Self {
        let shape = t.dims().to_vec();
        Self::new(shape.clone(), t.reshape(padded(&shape)))
    }
}

fn padded(shape: &[usize]) -> [usize; RANK] {
    assert!(
        shape.len() <= RANK,
        "evaluator: rank {} over {RANK}",
        shape.len()
    );
    let mut out = [1; RANK];
    out[RANK - shape.len()..].copy_from_slice(shape);
    out
}

fn expand(x: &Array, shape: &[usize]) -> T {
    if x.shape == shape {
        x.data.clone()
    } else {
        x.data.clone().expand(padded(shape))
    }
}

/// A node's attributes by name.
struct Attrs<'a>(&'a NodeProto);

impl Attrs<'_> {
    fn get(&self, name: &str) -> Option<&onnx_protobuf::AttributeProto> {
        self.0.attribute.iter().find(|a| a.name == name)
    }
    fn int(&self, name: &str) -> i64 {
        self.get(name)
            .unwrap_or_else(|| panic!("{}: no attribute {name}", self.0.name))
            .i
    }
    fn ints(&self, name: &str) -> Vec<usize> {
        let a = self
            .get(name)
            .unwrap_or_else(|| panic!("{}: no attribute {name}", self.0.name));
        a.ints.iter().map(|&v| to_usize(v)).collect()
    }
    fn float(&self, name: &str) -> f32 {
        self.get(name)
            .unwrap_or_else(|| panic!("{}: no attribute {name}", self.0.name))
            .f
    }
    fn string(&self, name: &str) -> String {
        let a = self
            .get(name)
            .unwrap_or_else(|| panic!("{}: no attribute {name}", self.0.name));
        String::from_utf8_lossy(&a.s).into_owned()
    }
}

fn to_usize(v: i64) -> usize {
    usize::try_from(v).unwrap_or_else(|_| panic!("evaluator: negative or huge index {v}"))
}

/// The evaluation state: float values and int64 initializers by name.
#[derive(Default)]
struct Values {
    floats: HashMap<String, Array>,
    ints: HashMap<String, Vec<i64>>,
}

impl Values {
    fn float(&self, name: &str) -> &Array {
        self.floats
            .get(name)
            .unwrap_or_else(|| panic!("evaluator: value {name} is not defined before its use"))
    }
    fn ints(&self, name: &str) -> &[i64] {
        self.ints
            .get(name)
            .unwrap_or_else(|| panic!("evaluator: int64 input {name} is not an initializer"))
    }
    fn initializer(&mut self, t: &TensorProto) {
        let shape: Vec<usize> = t.dims.iter().map(|&d| to_usize(d)).collect();
        if t.data_type == DataType::INT64 as i32 {
            let v = t.raw_data.chunks_exact(8);
            let v = v.map(|b| i64::from_le_bytes(b.try_into().expect("8 bytes")));
            self.ints.insert(t.name.clone(), v.collect());
        } else {
            assert_eq!(t.data_type, DataType::FLOAT as i32, "{}: dtype", t.name);
            let v = t.raw_data.chunks_exact(4);
            let v = v.map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")));
            let array = Array::from_values(&shape, v.collect());
            self.floats.insert(t.name.clone(), array);
        }
    }
}

/// Runs `model` on `inputs` (by graph input name) and returns its outputs in order.
pub(crate) fn evaluate(model: &ModelProto, inputs: &[(&str, TensorData)]) -> Vec<TensorData> {
    let graph = model.graph.as_ref().expect("a graph");
    let mut values = Values::default();
    for t in &graph.initializer {
        values.initializer(t);
    }
    for info in &graph.input {
        let (_, data) = inputs
            .iter()
            .find(|(name, _)| *name == info.name)
            .unwrap_or_else(|| panic!("evaluator: no value for input {}", info.name));
        let shape = data.shape.to_vec();
        let array = Array::from_values(&shape, data.to_vec().expect("float32 input"));
        values.floats.insert(info.name.clone(), array);
    }
    for node in &graph.node {
        let out = run(node, &values);
        assert_eq!(node.output.len(), 1, "{}: one output", node.name);
        values.floats.insert(node.output[0].clone(), out);
    }
    graph
        .output
        .iter()
        .map(|o| values.float(&o.name).to_data())
        .collect()
}

/// Builds a graph whose inputs are `inputs` (named `input0`, `input1`, …), lets `emit` write its
/// nodes, names what `emit` returns as outputs, and evaluates it: a module's `emit` as numbers.
pub(crate) fn run_emitted(
    inputs: &[TensorData],
    emit: impl FnOnce(&mut Graph, &[Value]) -> Vec<Value>,
) -> Vec<TensorData> {
    let mut g = Graph::default();
    let names: Vec<String> = (0..inputs.len()).map(|i| format!("input{i}")).collect();
    let values: Vec<Value> = names
        .iter()
        .zip(inputs)
        .map(|(name, data)| g.input(name, &data.shape))
        .collect();
    let outputs = emit(&mut g, &values);
    for (i, v) in outputs.iter().enumerate() {
        g.output(v, &format!("output{i}"));
    }
    let model = g.into_model("module", "a module's emit, evaluated by its test");
    let named: Vec<(&str, TensorData)> = names
        .iter()
        .map(String::as_str)
        .zip(inputs.iter().cloned())
        .collect();
    evaluate(&model, &named)
}

/// Asserts that the graph's value `emitted` equals `forward`'s within `bound` relative to the
/// largest magnitude of `forward` (at least 1), and returns the largest difference.
pub(crate) fn assert_emit_matches(
    label: &str,
    emitted: &TensorData,
    forward: TensorData,
    bound: f32,
) -> f32 {
    assert_eq!(emitted.shape, forward.shape, "{label}: shapes");
    let (a, b) = (
        emitted.to_vec::<f32>().expect("float32"),
        forward.convert::<f32>().to_vec::<f32>().expect("float32"),
    );
    let scale = b.iter().fold(1f32, |m, v| m.max(v.abs()));
    // f32::max drops a NaN, so a NaN on either side is refused before the largest difference.
    let nan = a.iter().chain(&b).position(|v| v.is_nan());
    assert!(
        nan.is_none(),
        "{label}: NaN in emit or forward (value {nan:?})"
    );
    let diff = a
        .iter()
        .zip(&b)
        .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(
        diff <= bound * scale,
        "{label}: emit differs from forward by {diff} (largest |forward| {scale}, bound {bound} relative)"
    );
    diff
}

/// A node being evaluated: its inputs and attributes.
struct Node<'a> {
    proto: &'a NodeProto,
    values: &'a Values,
}

impl Node<'_> {
    fn input(&self, i: usize) -> &Array {
        self.values.float(&self.proto.input[i])
    }

    /// An int64 input (shapes, axes, slice bounds) as indices.
    fn indices(&self, i: usize) -> Vec<usize> {
        let v = self.values.ints(&self.proto.input[i]);
        v.iter().map(|&d| to_usize(d)).collect()
    }

    fn attrs(&self) -> Attrs<'_> {
        Attrs(self.proto)
    }

    fn name(&self) -> &str {
        &self.proto.name
    }
}

fn run(proto: &NodeProto, values: &Values) -> Array {
    let node = Node { proto, values };
    match proto.op_type.as_str() {
        "Identity" => node.input(0).clone(),
        "Add" | "Sub" | "Mul" | "Div" | "Min" => binary(&node),
        "Relu" | "Sigmoid" | "Tanh" | "Neg" | "Sqrt" | "Exp" | "Reciprocal" => unary(&node),
        "Reshape" | "Transpose" | "Concat" | "Slice" => reshaping(&node),
        "ReduceMean" | "ReduceSum" | "Softmax" | "LayerNormalization" => reducing(&node),
        "MatMul" => matmul(node.input(0), node.input(1)),
        "Conv" | "AveragePool" | "GridSample" => spatial(&node),
        other => panic!(
            "evaluator: op type {other} ({}) is not implemented",
            node.name()
        ),
    }
}

fn binary(node: &Node) -> Array {
    let (a, b) = (node.input(0), node.input(1));
    let shape = broadcast(&a.shape, &b.shape);
    let (a, b) = (expand(a, &shape), expand(b, &shape));
    let data = match node.proto.op_type.as_str() {
        "Add" => a + b,
        "Sub" => a - b,
        "Mul" => a * b,
        "Div" => a / b,
        "Min" => a.min_pair(b),
        other => unreachable!("{other}"),
    };
    Array::new(shape, data)
}

fn unary(node: &Node) -> Array {
    let x = node.input(0);
    let t = x.data.clone();
    let data = match node.proto.op_type.as_str() {
        "Relu" => relu(t),
        "Sigmoid" => sigmoid(t),
        "Tanh" => t.tanh(),
        "Neg" => t.neg(),
        "Sqrt" => t.sqrt(),
        "Exp" => t.exp(),
        "Reciprocal" => t.recip(),
        other => unreachable!("{other}"),
    };
    Array::new(x.shape.clone(), data)
}

fn reshaping(node: &Node) -> Array {
    let x = node.input(0);
    match node.proto.op_type.as_str() {
        "Reshape" => {
            let shape = node.indices(1);
            Array::new(shape.clone(), x.data.clone().reshape(padded(&shape)))
        }
        "Transpose" => {
            let perm = node.attrs().ints("perm");
            let lead = RANK - perm.len();
            let mut full = [0; RANK];
            for (i, slot) in full.iter_mut().enumerate() {
                *slot = if i < lead { i } else { lead + perm[i - lead] };
            }
            let shape = perm.iter().map(|&p| x.shape[p]).collect();
            Array::new(shape, x.data.clone().permute(full))
        }
        "Concat" => {
            let axis = to_usize(node.attrs().int("axis"));
            let parts: Vec<&Array> = (0..node.proto.input.len()).map(|i| node.input(i)).collect();
            let mut shape = parts[0].shape.clone();
            shape[axis] = parts.iter().map(|p| p.shape[axis]).sum();
            let tensors = parts.iter().map(|p| p.data.clone()).collect();
            Array::new(shape, crate::cat(tensors, parts[0].axis(axis)))
        }
        "Slice" => {
            let [start, end, axis] = [1, 2, 3].map(|i| match node.indices(i)[..] {
                [v] => v,
                _ => panic!("{}: one axis per Slice", node.name()),
            });
            let mut shape = x.shape.clone();
            shape[axis] = end - start;
            let data = x.data.clone().narrow(x.axis(axis), start, end - start);
            Array::new(shape, data)
        }
        other => unreachable!("{other}"),
    }
}

fn reducing(node: &Node) -> Array {
    let x = node.input(0);
    let attrs = node.attrs();
    match node.proto.op_type.as_str() {
        op @ ("ReduceMean" | "ReduceSum") => {
            assert_eq!(attrs.int("keepdims"), 1, "{}: keepdims", node.name());
            // Opset 17: ReduceMean's axes are an attribute, ReduceSum's an input.
            let axes = if op == "ReduceMean" {
                attrs.ints("axes")
            } else {
                node.indices(1)
            };
            let (mut shape, mut data) = (x.shape.clone(), x.data.clone());
            for axis in axes {
                let a = x.axis(axis);
                data = if op == "ReduceMean" {
                    data.mean_dim(a)
                } else {
                    data.sum_dim(a)
                };
                shape[axis] = 1;
            }
            Array::new(shape, data)
        }
        "Softmax" => {
            let axis = x.axis(to_usize(attrs.int("axis")));
            Array::new(x.shape.clone(), softmax(x.data.clone(), axis))
        }
        "LayerNormalization" => {
            let (gamma, beta) = (node.input(1), node.input(2));
            assert_eq!(attrs.int("axis"), -1, "{}: the last axis", node.name());
            let eps = f64::from(attrs.float("epsilon"));
            let last = RANK - 1;
            let mean = x.data.clone().mean_dim(last);
            let centred = x.data.clone() - mean;
            let var = centred.clone().square().mean_dim(last);
            let normed = centred / var.add_scalar(eps).sqrt();
            let data = normed * expand(gamma, &x.shape) + expand(beta, &x.shape);
            Array::new(x.shape.clone(), data)
        }
        other => unreachable!("{other}"),
    }
}

/// A batched matrix product with NumPy broadcasting of the leading axes.
fn matmul(a: &Array, b: &Array) -> Array {
    let (ra, rb) = (a.shape.len(), b.shape.len());
    let mut batch = broadcast(&a.shape[..ra - 2], &b.shape[..rb - 2]);
    let (m, k, n) = (a.shape[ra - 2], a.shape[ra - 1], b.shape[rb - 1]);
    let with = |tail: [usize; 2]| [batch.clone(), tail.to_vec()].concat();
    let (sa, sb) = (with([m, k]), with([k, n]));
    let a = expand(&reshaped(a, sa.len()), &sa);
    let data = a.matmul(expand(&reshaped(b, sb.len()), &sb));
    batch.extend([m, n]);
    Array::new(batch, data)
}

fn spatial(node: &Node) -> Array {
    let attrs = node.attrs();
    let x = node.input(0).nchw();
    let y = match node.proto.op_type.as_str() {
        "Conv" => {
            let w = node.input(1).nchw();
            let bias = (node.proto.input.len() > 2).then(|| {
                let b = node.input(2);
                b.data.clone().reshape([b.shape[0]])
            });
            let (pads, stride) = (attrs.ints("pads"), attrs.ints("strides"));
            let dilation = attrs.ints("dilations");
            let options = PaddedConvOptions::asymmetric(
                [stride[0], stride[1]],
                [pads[0], pads[1]],
                [pads[2], pads[3]],
                [dilation[0], dilation[1]],
                to_usize(attrs.int("group")),
            );
            conv2d(x, w, bias, options)
        }
        "AveragePool" => {
            let (k, s) = (attrs.ints("kernel_shape"), attrs.ints("strides"));
            avg_pool2d(x, [k[0], k[1]], [s[0], s[1]], [0, 0], true, false)
        }
        "GridSample" => {
            assert_eq!(attrs.int("align_corners"), 1, "{}", node.name());
            assert_eq!(attrs.string("mode"), "bilinear", "{}", node.name());
            assert_eq!(attrs.string("padding_mode"), "zeros", "{}", node.name());
            let options = GridSampleOptions::new(InterpolateMode::Bilinear)
                .with_padding_mode(GridSamplePaddingMode::Zeros)
                .with_align_corners(true);
            x.grid_sample_2d(node.input(1).nchw(), options)
        }
        other => unreachable!("{other}"),
    };
    Array::from_nchw(y)
}

/// `x` with leading axes of size 1 added up to rank `rank` (its padded data is unchanged).
fn reshaped(x: &Array, rank: usize) -> Array {
    let mut shape = vec![1; rank - x.shape.len()];
    shape.extend(&x.shape);
    Array::new(shape, x.data.clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(shape: &[usize], f: impl Fn(usize) -> f32) -> TensorData {
        let n = shape.iter().product();
        TensorData::new((0..n).map(f).collect::<Vec<f32>>(), shape.to_vec())
    }

    /// The evaluator against numbers worked out by hand: a broadcast, a transpose, a matrix
    /// product with a broadcast batch, a slice, a sum and a 2×2 average pool.
    #[test]
    fn small_graphs_give_the_numbers_worked_out_by_hand() {
        let a = data(&[2, 3], |i| i as f32); // [[0,1,2],[3,4,5]]
        let b = data(&[3], |i| 10.0 * i as f32); // [0,10,20]
        let out = run_emitted(&[a, b], |g, x| {
            let sum = g.add(&x[0], &x[1]); // [[0,11,22],[3,14,25]]
            let t = g.transpose(&sum, &[1, 0]); // 3×2
            let p = g.matmul(&sum, &t); // 2×2
            let s = g.narrow(&sum, 1, 1, 2); // [[11,22],[14,25]]
            let r = g.sum_dim(&s, 0); // [[25,47]]
            let img = g.reshape(&x[0], &[1, 1, 2, 3]);
            let img = g.narrow(&img, 3, 0, 2);
            let pool = g.avg_pool(&img, 2); // mean of 0,1,3,4
            vec![p, r, pool]
        });
        let v = |t: &TensorData| t.to_vec::<f32>().unwrap();
        assert_eq!(
            v(&out[0]),
            [
                0.0 + 121.0 + 484.0,
                154.0 + 550.0,
                154.0 + 550.0,
                9.0 + 196.0 + 625.0
            ]
        );
        assert_eq!(out[0].shape.to_vec(), vec![2, 2]);
        assert_eq!(v(&out[1]), [25.0, 47.0]);
        assert_eq!(v(&out[2]), [2.0]);
    }

    /// A node the evaluator does not know is refused by name, not skipped.
    #[test]
    #[should_panic(expected = "op type Floor")]
    fn an_unknown_op_is_refused() {
        run_emitted(&[data(&[2], |i| i as f32)], |g, x| {
            vec![g.unary("Floor", &x[0])]
        });
    }

    /// A NaN on either side fails the comparison (f32::max alone would skip it).
    #[test]
    #[should_panic(expected = "NaN in emit or forward")]
    fn a_nan_fails_the_comparison() {
        let a = TensorData::new(vec![1.0f32, f32::NAN], [2]);
        let b = TensorData::new(vec![1.0f32, 2.0], [2]);
        assert_emit_matches("nan", &a, b, 1e-5);
    }
}
