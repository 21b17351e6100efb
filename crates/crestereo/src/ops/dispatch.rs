//! The one place that decides, per call, whether an op runs a hand-written kernel or its
//! composed Burn-ops version.
//!
//! Every op with a kernel (AGCL offset correlation, warp and shift correlation, convolutions,
//! GRU gates, convex upsampling) keeps a composed version built from Burn tensor ops. That
//! version runs on every backend and dtype, is the fallback where no kernel exists, and is the
//! reference its kernels are tested against. [`kernels`] names the kernel family of a backend
//! type (or [`Kernels::Composed`]); [`use_composed_ops`] (or `CRESTEREO_KERNELS=composed` in
//! the environment) switches every kernel off, so any backend's numbers can be reproduced with
//! the composed ops on the CPU.
//!
//! The network stays generic over `B: Backend`; where `B` is a backend a kernel is written for,
//! the tensor primitives are moved (not copied) to the kernel's concrete type and back with
//! [`same`], checked at run time.
//!
//! Every op with a kernel is called the same way: its entry point matches on
//! [`kernels_f32`] of its inputs, one arm per kernel family it has (`Kernels::Flex` through
//! [`to_flex`] / [`from_flex`], `Kernels::AutodiffFlex` through [`to_autodiff_flex`] /
//! [`from_autodiff_flex`]; the AGCL ops, whose kernels exist for every family, through
//! [`on_kernel_backend`], which writes one arm per family), and a last arm that calls the op's
//! composed version, named `composed::<op>` in the op's own module.

use std::any::{Any, TypeId};
use std::sync::atomic::{AtomicU8, Ordering};

use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use burn::tensor::ops::FloatTensor;
use burn::tensor::{DType, TensorPrimitive};

/// The kernel family serving a backend type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernels {
    /// Flex CPU kernels (inference).
    Flex,
    /// Flex CPU kernels recorded with their own backward (training).
    AutodiffFlex,
    /// CubeCL kernels on CUDA (the AGCL ops; other ops compose Burn's CUDA kernels).
    #[cfg(feature = "cuda")]
    Cuda,
    #[cfg(feature = "cuda")]
    AutodiffCuda,
    /// CubeCL kernels on wgpu (Vulkan via SPIR-V, Metal, DX12), where the device has float
    /// atomics (the AGCL backward's scatters need them).
    #[cfg(feature = "wgpu")]
    Wgpu,
    #[cfg(feature = "wgpu")]
    AutodiffWgpu,
    /// No kernel: Burn tensor ops only.
    Composed,
}

/// The CUDA backend the network's kernels are written for (`burn::backend::Cuda`).
#[cfg(feature = "cuda")]
pub type CudaBackend = burn::backend::Cuda;
/// The wgpu backend the network's kernels are written for (`burn::backend::Wgpu`, default
/// element types; with the `vulkan` feature it compiles kernels to SPIR-V).
#[cfg(feature = "wgpu")]
pub type WgpuBackend = burn::backend::Wgpu;

const UNSET: u8 = 0;
const KERNELS: u8 = 1;
const COMPOSED: u8 = 2;
static CHOICE: AtomicU8 = AtomicU8::new(UNSET);

/// Switches every hand-written kernel off (`true`) or back on (`false`) for the whole process.
pub fn use_composed_ops(composed: bool) {
    CHOICE.store(if composed { COMPOSED } else { KERNELS }, Ordering::Relaxed);
}

/// Whether the kernels are switched off: by [`use_composed_ops`], else by the environment
/// (`CRESTEREO_KERNELS=composed`, read once).
pub fn composed_only() -> bool {
    match CHOICE.load(Ordering::Relaxed) {
        UNSET => {
            let composed = std::env::var("CRESTEREO_KERNELS").is_ok_and(|v| v == "composed");
            // A concurrent `use_composed_ops` wins over the environment.
            let _ = CHOICE.compare_exchange(
                UNSET,
                if composed { COMPOSED } else { KERNELS },
                Ordering::Relaxed,
                Ordering::Relaxed,
            );
            CHOICE.load(Ordering::Relaxed) == COMPOSED
        }
        v => v == COMPOSED,
    }
}

/// The kernel family for backend `B` and float32 tensors (kernels are float32 only), or
/// [`Kernels::Composed`].
pub fn kernels<B: Backend>(device: &B::Device) -> Kernels {
    let _ = device; // only the wgpu check needs it
    if composed_only() {
        return Kernels::Composed;
    }
    let id = TypeId::of::<B>();
    if id == TypeId::of::<Flex>() {
        return Kernels::Flex;
    }
    if id == TypeId::of::<Autodiff<Flex>>() {
        return Kernels::AutodiffFlex;
    }
    #[cfg(feature = "cuda")]
    {
        if id == TypeId::of::<CudaBackend>() {
            return Kernels::Cuda;
        }
        if id == TypeId::of::<Autodiff<CudaBackend>>() {
            return Kernels::AutodiffCuda;
        }
    }
    #[cfg(feature = "wgpu")]
    {
        let plain = id == TypeId::of::<WgpuBackend>();
        if plain || id == TypeId::of::<Autodiff<WgpuBackend>>() {
            let device: &burn::backend::wgpu::WgpuDevice = same_ref(device);
            if wgpu_has_float_atomics(device) {
                return if plain {
                    Kernels::Wgpu
                } else {
                    Kernels::AutodiffWgpu
                };
            }
        }
    }
    Kernels::Composed
}

/// Whether a wgpu device can add floats atomically (Vulkan via SPIR-V on most drivers,
/// lavapipe included; not WGSL). The backward kernels' scatters need it; without it the
/// dispatch runs the composed ops. Asked once per device (the dispatch asks on every op).
#[cfg(feature = "wgpu")]
pub(crate) fn wgpu_has_float_atomics(device: &burn::backend::wgpu::WgpuDevice) -> bool {
    use burn::backend::wgpu::WgpuDevice;
    use burn_cubecl::cubecl::features::AtomicUsage;
    use burn_cubecl::cubecl::ir::{FloatKind, StorageType, Type};
    static KNOWN: std::sync::Mutex<Vec<(WgpuDevice, bool)>> = std::sync::Mutex::new(Vec::new());
    let mut known = KNOWN.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, has)) = known.iter().find(|(d, _)| d == device) {
        return *has;
    }
    let client =
        <burn::backend::wgpu::WgpuRuntime as burn_cubecl::cubecl::prelude::Runtime>::client(device);
    let has = client
        .properties()
        .atomic_type_usage(Type::new(StorageType::Atomic(FloatKind::F32.into())))
        .contains(AtomicUsage::Add);
    known.push((device.clone(), has));
    has
}

/// The kernel family for `B` if every tensor is float32, else [`Kernels::Composed`].
pub fn kernels_f32<B: Backend, const D: usize>(tensors: &[&Tensor<B, D>]) -> Kernels {
    if tensors.iter().any(|t| t.dtype() != DType::F32) {
        return Kernels::Composed;
    }
    kernels::<B>(&tensors[0].device())
}

/// A tensor (or a kernel's result) on its way to or from a kernel's entry point
/// (`ops::compiled`), its type erased: generic code hands a GPU backend's tensors across without
/// naming their type, so it does not compile their drop (see `ops::compiled`).
pub(crate) type Erased = Box<dyn Any>;

/// `value` as an [`Erased`].
pub(crate) fn erase<S: 'static>(value: S) -> Erased {
    Box::new(value)
}

/// The value of type `T` inside `value` (checked at run time).
pub(crate) fn unerase<T: 'static>(value: Erased) -> T {
    *value
        .downcast::<T>()
        .unwrap_or_else(|_| unreachable!("kernel dispatch: backend types differ"))
}

/// Moves a value between two type names of the same type (checked at run time).
pub(crate) fn same<S: 'static, T: 'static>(value: S) -> T {
    *(Box::new(value) as Box<dyn Any>)
        .downcast::<T>()
        .unwrap_or_else(|_| unreachable!("kernel dispatch: backend types differ"))
}

/// A reference under another name of the same type (checked at run time).
#[cfg(feature = "wgpu")]
fn same_ref<S: 'static, T: 'static>(value: &S) -> &T {
    (value as &dyn Any)
        .downcast_ref::<T>()
        .unwrap_or_else(|| unreachable!("kernel dispatch: device types differ"))
}

/// The Flex tensor behind a tensor of `B` (which must be Flex: the caller matched
/// [`Kernels::Flex`]).
pub(crate) fn to_flex<B: Backend, const D: usize>(t: Tensor<B, D>) -> FlexTensor {
    same(t.into_primitive().tensor())
}

/// A Flex tensor as a tensor of `B` (which must be Flex).
pub(crate) fn from_flex<B: Backend, const D: usize>(t: FlexTensor) -> Tensor<B, D> {
    Tensor::from_primitive(TensorPrimitive::Float(same(t)))
}

/// The autodiff tensor behind a tensor of `B` (which must be `Autodiff<Flex>`: the caller
/// matched [`Kernels::AutodiffFlex`]).
pub(crate) fn to_autodiff_flex<B: Backend, const D: usize>(
    t: Tensor<B, D>,
) -> FloatTensor<Autodiff<Flex>> {
    same(t.into_primitive().tensor())
}

/// An `Autodiff<Flex>` tensor as a tensor of `B` (which must be `Autodiff<Flex>`).
pub(crate) fn from_autodiff_flex<B: Backend, const D: usize>(
    t: FloatTensor<Autodiff<Flex>>,
) -> Tensor<B, D> {
    Tensor::from_primitive(TensorPrimitive::Float(same(t)))
}

/// Runs `$kernel` with `$I` bound to the module of entry points (`ops::compiled`) of the
/// concrete backend behind `$B` when `$choice` names a kernel family of backends implementing
/// the AGCL kernels, `$composed` otherwise. The entry points have the `AgclOps` methods' names
/// and take and give the tensors erased ([`erase`], [`unerase`]): the kernels are compiled in
/// this crate once, not in every crate that instantiates the network.
macro_rules! on_kernel_backend {
    ($choice:expr, |$I:ident| $kernel:expr, composed => $composed:expr) => {{
        use $crate::ops::dispatch::Kernels;
        match $choice {
            Kernels::Flex => {
                use $crate::ops::compiled::flex as $I;
                $kernel
            }
            Kernels::AutodiffFlex => {
                use $crate::ops::compiled::autodiff_flex as $I;
                $kernel
            }
            #[cfg(feature = "cuda")]
            Kernels::Cuda => {
                use $crate::ops::compiled::cuda as $I;
                $kernel
            }
            #[cfg(feature = "cuda")]
            Kernels::AutodiffCuda => {
                use $crate::ops::compiled::autodiff_cuda as $I;
                $kernel
            }
            #[cfg(feature = "wgpu")]
            Kernels::Wgpu => {
                use $crate::ops::compiled::wgpu as $I;
                $kernel
            }
            #[cfg(feature = "wgpu")]
            Kernels::AutodiffWgpu => {
                use $crate::ops::compiled::autodiff_wgpu as $I;
                $kernel
            }
            Kernels::Composed => $composed,
        }
    }};
}
pub(crate) use on_kernel_backend;
