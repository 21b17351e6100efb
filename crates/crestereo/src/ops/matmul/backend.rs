//! The backend extension the fixed float32 matrix product is written against.

use burn::prelude::*;
use burn::tensor::ops::FloatTensor;

/// A backend with the fixed float32 matrix product.
pub trait MatmulOps: Backend {
    /// `lhs` (…, M, K) × `rhs` (…, K, N) → (…, M, N), equal batch dimensions, float32.
    fn f32_matmul(lhs: FloatTensor<Self>, rhs: FloatTensor<Self>) -> FloatTensor<Self>;
}
