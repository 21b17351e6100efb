//! Matrix products in full float32 on every CubeCL backend, with one fixed kernel.
//!
//! Burn's matrix product on a CubeCL backend autotunes: it compiles and times every candidate
//! kernel for each new shape class, and on NVIDIA GPUs its fastest candidates feed float32
//! inputs to the tensor cores as TensorFloat-32 (10-bit mantissa: products rounded at about
//! 5e-4 relative). Both cost what this project must not pay by default: autotuning compiles far
//! more kernels than the work runs (minutes of a cold start on CUDA), and TF32 moves a
//! 20-iteration disparity by hundredths of a pixel where the CPU backends agree with the
//! reference to 1e-4.
//!
//! So under [`Precision::F32`] (the default) every matrix product of the network on a CubeCL
//! backend (the attention's, and the stride-1 and strided convolutions, which run as one matrix
//! product over the unfolded input: `conv2d::by_matmul`) goes through [`matmul`], which runs
//! CubeCL's *unit* matmul — each thread multiplies and adds in float32 registers, no tensor
//! cores — with one fixed tiling and no autotuning: one kernel per shape class, full float32.
//! Its backward (under `Autodiff`) is two more such products. [`Precision::Tf32`]
//! (`--precision tf32`, `CRESTEREO_PRECISION=tf32`) hands matrix products and convolutions back
//! to Burn (autotuned, TF32 where the GPU has it). On Flex and any other backend [`matmul`] is
//! Burn's `matmul`.

#[cfg(feature = "cube")]
mod autodiff;
// The trait in a file of its own: `ops::compiled` implements its entry points with it, and this
// module calls those entry points (no import circle).
pub(crate) mod backend;
#[cfg(feature = "cube")]
mod cube;

pub use backend::MatmulOps;

use std::sync::atomic::{AtomicU8, Ordering};

use burn::prelude::*;
use burn::tensor::ops::FloatTensor;

use crate::ops::dispatch::{Kernels, kernels_f32};

/// How matrix products and convolutions run on CubeCL backends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Precision {
    /// Full float32: one fixed unit-matmul kernel per shape class, no autotuning.
    #[default]
    F32,
    /// Burn's autotuned kernels, TensorFloat-32 tensor cores where the GPU has them.
    Tf32,
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "f32" | "fp32" | "float32" => Ok(Precision::F32),
            "tf32" => Ok(Precision::Tf32),
            other => Err(format!("precision `{other}` is not f32 or tf32")),
        }
    }
}

const UNSET: u8 = 0;
const F32: u8 = 1;
const TF32: u8 = 2;
static PRECISION: AtomicU8 = AtomicU8::new(UNSET);

/// Sets the precision of matrix products and convolutions for the whole process.
pub fn set_precision(p: Precision) {
    PRECISION.store(
        match p {
            Precision::F32 => F32,
            Precision::Tf32 => TF32,
        },
        Ordering::Relaxed,
    );
}

/// The precision in force: [`set_precision`]'s, else `CRESTEREO_PRECISION` (read once; an
/// unknown value is an error at the command line, here it keeps the default), else `F32`.
pub fn precision() -> Precision {
    match PRECISION.load(Ordering::Relaxed) {
        F32 => Precision::F32,
        TF32 => Precision::Tf32,
        _ => {
            let p: Precision = std::env::var("CRESTEREO_PRECISION")
                .ok()
                .and_then(|v| v.parse::<Precision>().ok())
                .unwrap_or_default();
            let code = if p == Precision::Tf32 { TF32 } else { F32 };
            let _ = PRECISION.compare_exchange(UNSET, code, Ordering::Relaxed, Ordering::Relaxed);
            precision()
        }
    }
}

/// Whether backend `B`'s matrix products run through the fixed float32 kernel here (a CubeCL
/// backend with the network's kernels, float32 tensors, [`Precision::F32`]).
pub fn runs_fixed_f32<B: Backend, const D: usize>(tensors: &[&Tensor<B, D>]) -> bool {
    fixed_family(tensors).is_some()
}

/// The CubeCL kernel family the fixed kernel runs on for these tensors, if it runs.
fn fixed_family<B: Backend, const D: usize>(tensors: &[&Tensor<B, D>]) -> Option<Kernels> {
    if precision() != Precision::F32 {
        return None;
    }
    match kernels_f32(tensors) {
        #[cfg(feature = "cuda")]
        k @ (Kernels::Cuda | Kernels::AutodiffCuda) => Some(k),
        #[cfg(feature = "wgpu")]
        k @ (Kernels::Wgpu | Kernels::AutodiffWgpu) => Some(k),
        _ => None,
    }
}

/// `lhs · rhs` (batched over the leading dimensions, as `Tensor::matmul`): the fixed float32
/// kernel on CubeCL backends under [`Precision::F32`], Burn's `matmul` elsewhere.
pub fn matmul<B: Backend, const D: usize>(lhs: Tensor<B, D>, rhs: Tensor<B, D>) -> Tensor<B, D> {
    match fixed_family(&[&lhs, &rhs]) {
        Some(family) => fixed_matmul(family, lhs, rhs),
        None => lhs.matmul(rhs),
    }
}

/// The fixed kernel on `family`. The batch dimensions are broadcast and flattened into one, so
/// the kernel always sees rank 3 with equal batches (one kernel variant per shape class,
/// whatever the caller's rank).
fn fixed_matmul<B: Backend, const D: usize>(
    family: Kernels,
    lhs: Tensor<B, D>,
    rhs: Tensor<B, D>,
) -> Tensor<B, D> {
    let (lhs, rhs) = equal_batches(lhs, rhs);
    let (l, r) = (lhs.dims(), rhs.dims());
    let batch: usize = l[..D - 2].iter().product();
    let (m, k, n) = (l[D - 2], l[D - 1], r[D - 1]);
    assert_eq!(r[D - 2], k, "matmul: inner dimensions {l:?} × {r:?}");
    let mut out = l;
    out[D - 1] = n;
    let lhs: Tensor<B, 3> = lhs.reshape([batch, m, k]);
    let rhs: Tensor<B, 3> = rhs.reshape([batch, k, n]);
    on_family(family, lhs, rhs).reshape(out)
}

/// [`MatmulOps::f32_matmul`] on the concrete backend behind `B` (`family`, from
/// [`fixed_family`]).
fn on_family<B: Backend>(family: Kernels, lhs: Tensor<B, 3>, rhs: Tensor<B, 3>) -> Tensor<B, 3> {
    #[cfg(feature = "cube")]
    {
        use crate::ops::dispatch::{erase, unerase};
        use burn::tensor::TensorPrimitive;
        let prim = |t: Tensor<B, 3>| -> FloatTensor<B> { t.into_primitive().tensor() };
        let back = |p: FloatTensor<B>| -> Tensor<B, 3> {
            Tensor::from_primitive(TensorPrimitive::Float(p))
        };
        // Each backend's product through its entry point in `ops::compiled` (compiled in this
        // crate once, not in every crate that instantiates the network).
        macro_rules! on {
            ($module:ident) => {
                back(unerase(crate::ops::compiled::$module::f32_matmul(
                    erase(prim(lhs)),
                    erase(prim(rhs)),
                )))
            };
        }
        match family {
            #[cfg(feature = "cuda")]
            Kernels::Cuda => return on!(cuda),
            #[cfg(feature = "cuda")]
            Kernels::AutodiffCuda => return on!(autodiff_cuda),
            #[cfg(feature = "wgpu")]
            Kernels::Wgpu => return on!(wgpu),
            #[cfg(feature = "wgpu")]
            Kernels::AutodiffWgpu => return on!(autodiff_wgpu),
            _ => {}
        }
    }
    #[cfg(not(feature = "cube"))]
    let _ = (lhs, rhs);
    unreachable!("the fixed float32 matmul has no kernel for {family:?}")
}

/// A [`burn::nn::Linear`] applied to `x` (…, in): with the fixed kernel where [`matmul`] takes
/// it (`x · W (+ b)`, W stored in × out, Burn's layout), else Burn's `Linear::forward`.
pub fn linear<B: Backend, const D: usize>(
    layer: &burn::nn::Linear<B>,
    x: Tensor<B, D>,
) -> Tensor<B, D> {
    let w = crate::ops::float_like(layer.weight.val(), x.dtype());
    let Some(family) = fixed_family(&[&w.clone().unsqueeze::<D>(), &x]) else {
        // Burn's own forward, bit for bit what the CPU parity was measured with.
        return layer.forward(x);
    };
    let dims = x.dims();
    let cin = dims[D - 1];
    let rows: usize = dims[..D - 1].iter().product();
    let cout = w.dims()[1];
    let y = fixed_matmul(family, x.reshape([1, rows, cin]), w.reshape([1, cin, cout]));
    let y = match &layer.bias {
        Some(b) => {
            let dtype = y.dtype();
            y + crate::ops::float_like(b.val(), dtype).reshape([1, 1, cout])
        }
        None => y,
    };
    let mut out = dims;
    out[D - 1] = cout;
    y.reshape(out)
}

/// `lhs` and `rhs` with their batch dimensions expanded to the common shape.
fn equal_batches<B: Backend, const D: usize>(
    lhs: Tensor<B, D>,
    rhs: Tensor<B, D>,
) -> (Tensor<B, D>, Tensor<B, D>) {
    let (l, r) = (lhs.dims(), rhs.dims());
    if l[..D - 2] == r[..D - 2] {
        return (lhs, rhs);
    }
    let mut ls = l;
    let mut rs = r;
    for d in 0..D - 2 {
        let n = l[d].max(r[d]);
        assert!(
            (l[d] == n || l[d] == 1) && (r[d] == n || r[d] == 1),
            "matmul: batch dimensions {l:?} and {r:?} do not broadcast"
        );
        ls[d] = n;
        rs[d] = n;
    }
    (lhs.expand(ls), rhs.expand(rs))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn precision_parses_and_defaults_to_f32() {
        assert_eq!("f32".parse::<Precision>(), Ok(Precision::F32));
        assert_eq!("TF32".parse::<Precision>(), Ok(Precision::Tf32));
        assert!("bf16".parse::<Precision>().is_err());
        assert_eq!(Precision::default(), Precision::F32);
    }

    #[test]
    fn linear_is_burns_linear() {
        type B = burn::backend::Flex;
        let d = Default::default();
        let layer = burn::nn::LinearConfig::new(6, 5).init::<B>(&d);
        let x = Tensor::<B, 3>::random([2, 3, 6], burn::tensor::Distribution::Default, &d);
        linear(&layer, x.clone())
            .into_data()
            .assert_approx_eq::<f32>(&layer.forward(x).into_data(), Default::default());
    }

    #[test]
    fn flex_matmul_is_burns() {
        type B = burn::backend::Flex;
        let d = Default::default();
        let a = Tensor::<B, 3>::random([2, 3, 4], burn::tensor::Distribution::Default, &d);
        let b = Tensor::<B, 3>::random([1, 4, 5], burn::tensor::Distribution::Default, &d);
        assert!(!runs_fixed_f32(&[&a, &b]));
        let ours = matmul(a.clone(), b.clone()).into_data();
        let burns = a.matmul(b).into_data();
        assert_eq!(ours, burns);
    }
}
