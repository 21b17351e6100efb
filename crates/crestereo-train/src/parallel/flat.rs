//! A model's gradients (or weights) as one flat tensor and back, in the order the model visits
//! its parameters — the same on every replica and process, unlike parameter ids, which are
//! random per process. One all-reduce of 5.4 M floats per step instead of 94 small ones.

use burn::module::{AutodiffModule, Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;

/// The float parameters of a module in visiting order: id and element count.
pub fn parameter_layout<B: Backend, M: Module<B>>(module: &M) -> Vec<(ParamId, usize)> {
    struct Layout(Vec<(ParamId, usize)>);
    impl<B: Backend> ModuleVisitor<B> for Layout {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<B, D>>) {
            self.0.push((param.id, param.shape().num_elements()));
        }
    }
    let mut layout = Layout(Vec::new());
    module.visit(&mut layout);
    layout.0
}

/// Elements of all float parameters.
pub fn parameter_count<B: Backend, M: Module<B>>(module: &M) -> usize {
    parameter_layout::<B, M>(module)
        .iter()
        .map(|(_, n)| n)
        .sum()
}

/// `grads` of `model`'s parameters laid end to end in visiting order (a parameter without a
/// gradient contributes zeros), consuming them.
pub fn flatten_gradients<B: AutodiffBackend, M: AutodiffModule<B>>(
    model: &M,
    grads: &mut GradientsParams,
    device: &B::Device,
) -> Tensor<B::InnerBackend, 1> {
    struct Take<'a, B: AutodiffBackend> {
        grads: &'a mut GradientsParams,
        parts: Vec<Tensor<B::InnerBackend, 1>>,
        device: B::Device,
    }
    impl<B: AutodiffBackend> ModuleVisitor<B> for Take<'_, B> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<B, D>>) {
            let n = param.shape().num_elements();
            let part = match self.grads.remove::<B::InnerBackend, D>(param.id) {
                Some(g) => g.reshape([n]),
                None => Tensor::zeros([n], &self.device),
            };
            self.parts.push(part);
        }
    }
    let mut take = Take::<B> {
        grads,
        parts: Vec::new(),
        device: device.clone(),
    };
    model.visit(&mut take);
    crestereo::cat(take.parts, 0)
}

/// The inverse of [`flatten_gradients`]: `flat` cut into `model`'s parameters' gradients.
pub fn unflatten_gradients<B: AutodiffBackend, M: AutodiffModule<B>>(
    model: &M,
    flat: Tensor<B::InnerBackend, 1>,
) -> GradientsParams {
    struct Put<B: AutodiffBackend> {
        flat: Tensor<B::InnerBackend, 1>,
        at: usize,
        grads: GradientsParams,
    }
    impl<B: AutodiffBackend> ModuleVisitor<B> for Put<B> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<B, D>>) {
            let shape = param.shape();
            let n = shape.num_elements();
            let part = self.flat.clone().slice(self.at..self.at + n).reshape(shape);
            self.at += n;
            self.grads.register::<B::InnerBackend, D>(param.id, part);
        }
    }
    let mut put = Put::<B> {
        flat,
        at: 0,
        grads: GradientsParams::new(),
    };
    model.visit(&mut put);
    put.grads
}

/// `module`'s float parameters laid end to end in visiting order.
pub fn flatten_parameters<B: Backend, M: Module<B>>(module: &M) -> Tensor<B, 1> {
    struct Gather<B: Backend>(Vec<Tensor<B, 1>>);
    impl<B: Backend> ModuleVisitor<B> for Gather<B> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<B, D>>) {
            let n = param.shape().num_elements();
            self.0.push(param.val().reshape([n]));
        }
    }
    let mut gather = Gather(Vec::new());
    module.visit(&mut gather);
    crestereo::cat(gather.0, 0)
}

/// `module` with its float parameters replaced by the slices of `flat` (same layout as
/// [`flatten_parameters`]); ids, and whether each needs a gradient, are kept.
pub fn load_flat_parameters<B: Backend, M: Module<B>>(module: M, flat: Tensor<B, 1>) -> M {
    struct Scatter<B: Backend> {
        flat: Tensor<B, 1>,
        at: usize,
    }
    impl<B: Backend> ModuleMapper<B> for Scatter<B> {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<B, D>>) -> Param<Tensor<B, D>> {
            let (id, tensor, mapper) = param.consume();
            let shape = tensor.shape();
            let n = shape.num_elements();
            let value = self.flat.clone().slice(self.at..self.at + n).reshape(shape);
            self.at += n;
            // The replacement keeps the parameter's autodiff tracking as it was.
            let value = if tensor.is_require_grad() {
                value.require_grad()
            } else {
                value
            };
            Param::from_mapped_value(id, value, mapper)
        }
    }
    module.map(&mut Scatter { flat, at: 0 })
}
