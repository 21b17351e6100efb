//! Hand-written kernels chosen from the backend type at run time.
//!
//! The network stays generic over `B: Backend`; where `B` is one of the backends a kernel is
//! written for, the tensor primitives are moved (not copied) to the kernel's concrete type and
//! back. [`same`] is that move, checked at run time.

use std::any::{Any, TypeId};

use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use burn::tensor::ops::FloatTensor;
use burn::tensor::{DType, TensorPrimitive};

/// Moves a value between two type names of the same type (checked at run time).
pub(crate) fn same<S: 'static, T: 'static>(value: S) -> T {
    *(Box::new(value) as Box<dyn Any>)
        .downcast::<T>()
        .unwrap_or_else(|_| unreachable!("kernel dispatch: backend types differ"))
}

/// Whether `B` is the plain (non-autodiff) Flex CPU backend.
pub(crate) fn is_flex<B: Backend>() -> bool {
    TypeId::of::<B>() == TypeId::of::<Flex>()
}

/// Whether `B` is the Flex CPU backend under Burn's autodiff (training).
pub(crate) fn is_autodiff_flex<B: Backend>() -> bool {
    TypeId::of::<B>() == TypeId::of::<Autodiff<Flex>>()
}

/// The Flex tensors behind float32 tensors of a Flex backend, or `None` (another backend or
/// dtype: the caller takes its composed path).
pub(crate) fn flex_f32<B: Backend, const D: usize, const K: usize>(
    tensors: [&Tensor<B, D>; K],
) -> Option<[FlexTensor; K]> {
    if !is_flex::<B>() || tensors.iter().any(|t| t.dtype() != DType::F32) {
        return None;
    }
    Some(tensors.map(|t| same(t.clone().into_primitive().tensor())))
}

/// A Flex tensor as a tensor of `B` (which must be Flex).
pub(crate) fn from_flex<B: Backend, const D: usize>(t: FlexTensor) -> Tensor<B, D> {
    Tensor::from_primitive(TensorPrimitive::Float(same(t)))
}

/// The autodiff tensors behind float32 tensors of `Autodiff<Flex>`, or `None` (another backend
/// or dtype: the caller takes its composed path).
pub(crate) fn autodiff_flex_f32<B: Backend, const D: usize, const K: usize>(
    tensors: [&Tensor<B, D>; K],
) -> Option<[FloatTensor<Autodiff<Flex>>; K]> {
    if !is_autodiff_flex::<B>() || tensors.iter().any(|t| t.dtype() != DType::F32) {
        return None;
    }
    Some(tensors.map(|t| same(t.clone().into_primitive().tensor())))
}

/// An `Autodiff<Flex>` tensor as a tensor of `B` (which must be `Autodiff<Flex>`).
pub(crate) fn from_autodiff_flex<B: Backend, const D: usize>(
    t: FloatTensor<Autodiff<Flex>>,
) -> Tensor<B, D> {
    Tensor::from_primitive(TensorPrimitive::Float(same(t)))
}
