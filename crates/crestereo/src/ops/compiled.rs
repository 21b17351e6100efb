//! The GPU kernels' entry points, one module per concrete GPU backend, compiled in this crate and
//! nowhere else.
//!
//! The AGCL and matrix-product kernels are written once for every CubeCL runtime (generic over
//! it), and the network calls them from its own generic code. Had the dispatch arms called the
//! generic methods directly, every crate that instantiates the network — each test binary, the
//! `crestereo` binary — would compile CubeCL's kernel-building code, Burn's fusion layer and
//! these launches again, for every GPU backend, even a test that runs only on the CPU (optimised
//! builds do not share generic instantiations between crates): about three quarters of the
//! machine code of the network's CPU-only test binaries. These functions are not generic, so they
//! are compiled here, once, and the dispatch arms (`on_kernel_backend!`, the fixed matmul's
//! families) call them.
//!
//! The crate's own unit-test build runs no GPU (the GPU tests are the trainer's, on lavapipe), so
//! it leaves the kernels out: there these functions only say that they cannot run.

use burn::tensor::ops::FloatTensor;

use super::agcl::CorrSpec;

/// One entry point: the call, not inlined into the caller (so compiled here); in this crate's
/// unit-test build, a function that says it cannot run.
macro_rules! entry {
    (fn $name:ident($($arg:ident: $ty:ty),*) -> $ret:ty = $call:expr) => {
        #[cfg(not(test))]
        #[inline(never)]
        pub(crate) fn $name($($arg: $ty),*) -> $ret {
            $call
        }
        #[cfg(test)]
        pub(crate) fn $name($($arg: $ty),*) -> $ret {
            let _ = ($($arg),*);
            unreachable!("this crate's unit-test build has no GPU kernels")
        }
    };
}

/// The module of entry points for backend `$backend`, its functions named as the trait methods
/// they call: those the network's dispatch calls (the warp's backward runs only inside the
/// autodiff backend's own graph, which `agcl_warp` records here).
macro_rules! entry_points {
    ($module:ident, $backend:ty) => {
        pub(crate) mod $module {
            #[allow(unused_imports)]
            use crate::ops::{agcl::AgclOps, matmul::MatmulOps};

            use super::{CorrSpec, FloatTensor};

            type B = $backend;

            entry!(fn f32_matmul(lhs: FloatTensor<B>, rhs: FloatTensor<B>) -> FloatTensor<B>
                = <B as MatmulOps>::f32_matmul(lhs, rhs));
            entry!(fn agcl_offset_corr(
                left: FloatTensor<B>,
                right: FloatTensor<B>,
                flow: FloatTensor<B>,
                offset: FloatTensor<B>,
                spec: CorrSpec
            ) -> FloatTensor<B>
                = <B as AgclOps>::agcl_offset_corr(left, right, flow, offset, spec));
            entry!(fn agcl_offset_corr_backward(
                left: FloatTensor<B>,
                right: FloatTensor<B>,
                flow: FloatTensor<B>,
                offset: FloatTensor<B>,
                grad: FloatTensor<B>,
                spec: CorrSpec,
                need: [bool; 4]
            ) -> [Option<FloatTensor<B>>; 4]
                = <B as AgclOps>::agcl_offset_corr_backward(
                    left, right, flow, offset, grad, spec, need
                ));
            entry!(fn agcl_warp(right: FloatTensor<B>, flow: FloatTensor<B>) -> FloatTensor<B>
                = <B as AgclOps>::agcl_warp(right, flow));
        }
    };
}

#[cfg(feature = "wgpu")]
entry_points!(wgpu, crate::ops::dispatch::WgpuBackend);
#[cfg(feature = "wgpu")]
entry_points!(
    autodiff_wgpu,
    burn::backend::Autodiff<crate::ops::dispatch::WgpuBackend>
);
#[cfg(feature = "cuda")]
entry_points!(cuda, crate::ops::dispatch::CudaBackend);
#[cfg(feature = "cuda")]
entry_points!(
    autodiff_cuda,
    burn::backend::Autodiff<crate::ops::dispatch::CudaBackend>
);
