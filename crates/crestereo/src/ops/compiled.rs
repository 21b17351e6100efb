//! The kernels' entry points, one module per concrete backend, compiled in this crate and nowhere
//! else.
//!
//! The AGCL and matrix-product kernels are written once for every CubeCL runtime (generic over
//! it), and the network calls them from its own generic code. Had the dispatch arms called the
//! generic methods directly, every crate that instantiates the network — each test binary, the
//! `crestereo` binary — would compile CubeCL's kernel-building code, Burn's fusion engine and
//! these launches again, for every GPU backend, even a test that runs only on the CPU (optimised
//! builds do not share generic instantiations between crates): about three quarters of the
//! machine code of the network's CPU-only test binaries. So the entry points are not generic,
//! and they take and give the tensors type-erased ([`Erased`]): the network's generic code never
//! holds a GPU tensor of a backend it does not run on, whose drop alone (a fusion tensor's drop
//! is an operation on the fusion stream) would pull that engine in again.
//!
//! The crate's own unit-test build runs no GPU (the GPU tests are the trainer's, on lavapipe), so
//! it leaves the GPU kernels out: there those functions only say that they cannot run.

#![allow(clippy::too_many_arguments)]

use burn::tensor::ops::FloatTensor;

use super::agcl::CorrSpec;
use super::dispatch::{Erased, erase, unerase};

/// One entry point: the erased tensors `$t` back to the module's backend `B`, the call, its
/// result erased; not inlined into callers, so compiled here. A `gpu` entry point is, in this
/// crate's unit-test build, a function that says it cannot run.
macro_rules! entry {
    (cpu fn $name:ident($($t:ident),*; $($arg:ident: $ty:ty),*) = $call:expr) => {
        #[inline(never)]
        pub(crate) fn $name($($t: Erased,)* $($arg: $ty),*) -> Erased {
            $(let $t: FloatTensor<B> = unerase($t);)*
            erase($call)
        }
    };
    (gpu fn $name:ident($($t:ident),*; $($arg:ident: $ty:ty),*) = $call:expr) => {
        #[cfg(not(test))]
        entry!(cpu fn $name($($t),*; $($arg: $ty),*) = $call);
        #[cfg(test)]
        pub(crate) fn $name($($t: Erased,)* $($arg: $ty),*) -> Erased {
            let _ = ($($t,)* $($arg,)*);
            unreachable!("this crate's unit-test build has no GPU kernels")
        }
    };
}

/// The AGCL entry points the network's dispatch calls (`on_kernel_backend!`), named as the
/// `AgclOps` methods they call. The warp's backward runs only inside the autodiff backend's own
/// graph, which `agcl_warp` records here.
macro_rules! agcl_entries {
    ($kind:ident) => {
        entry!($kind fn agcl_offset_corr(left, right, flow, offset; spec: CorrSpec)
            = <B as AgclOps>::agcl_offset_corr(left, right, flow, offset, spec));
        entry!($kind fn agcl_offset_corr_backward(left, right, flow, offset, grad;
                spec: CorrSpec, need: [bool; 4])
            = <B as AgclOps>::agcl_offset_corr_backward(
                left, right, flow, offset, grad, spec, need
            ));
        entry!($kind fn agcl_warp(right, flow;) = <B as AgclOps>::agcl_warp(right, flow));
    };
}

/// The module of entry points for backend `$backend`: the AGCL kernels, and on a GPU backend
/// the fixed float32 matrix product.
macro_rules! entry_points {
    (cpu $module:ident, $backend:ty) => {
        pub(crate) mod $module {
            use crate::ops::agcl::AgclOps;

            use super::{CorrSpec, Erased, FloatTensor, erase, unerase};

            type B = $backend;

            agcl_entries!(cpu);
        }
    };
    (gpu $module:ident, $backend:ty) => {
        pub(crate) mod $module {
            #[allow(unused_imports)]
            use crate::ops::{agcl::AgclOps, matmul::backend::MatmulOps};

            #[allow(unused_imports)]
            use super::{CorrSpec, Erased, FloatTensor, erase, unerase};

            // (Unused in the unit-test build, whose GPU entry points only refuse.)
            #[allow(dead_code)]
            type B = $backend;

            agcl_entries!(gpu);
            entry!(gpu fn f32_matmul(lhs, rhs;) = <B as MatmulOps>::f32_matmul(lhs, rhs));
        }
    };
}

entry_points!(cpu flex, burn::backend::Flex);
entry_points!(cpu autodiff_flex, burn::backend::Autodiff<burn::backend::Flex>);
#[cfg(feature = "wgpu")]
entry_points!(gpu wgpu, crate::ops::dispatch::WgpuBackend);
#[cfg(feature = "wgpu")]
entry_points!(
    gpu autodiff_wgpu,
    burn::backend::Autodiff<crate::ops::dispatch::WgpuBackend>
);
#[cfg(feature = "cuda")]
entry_points!(gpu cuda, crate::ops::dispatch::CudaBackend);
#[cfg(feature = "cuda")]
entry_points!(
    gpu autodiff_cuda,
    burn::backend::Autodiff<crate::ops::dispatch::CudaBackend>
);
