//! Concatenation along channels, the plain-Flex case copied in parallel.
//!
//! Flex concatenates on the calling thread; in inference the GRU input `[h, x]` and the update
//! block's `[context, motion]` are concatenated every iteration, and the other threads wait.

use burn::backend::flex::FlexTensor;
use burn::prelude::*;
use burn::tensor::{TensorData, TensorMetadata};
use rayon::prelude::*;

use crate::dispatch::{Kernels, from_flex, kernels_f32};

/// `Tensor::cat(parts, 1)` for (N, C_i, H, W) maps: the same values, copied plane by plane in
/// parallel when the backend is plain Flex with float32 maps.
pub(crate) fn cat_channels<B: Backend>(parts: Vec<Tensor<B, 4>>) -> Tensor<B, 4> {
    let refs: Vec<&Tensor<B, 4>> = parts.iter().collect();
    if parts.len() < 2 || kernels_f32(&refs) != Kernels::Flex {
        return Tensor::cat(parts, 1);
    }
    let flex: Vec<FlexTensor> = parts
        .into_iter()
        .map(|t| crate::dispatch::same(t.into_primitive().tensor()))
        .collect();
    from_flex(cat_flex(&flex))
}

fn cat_flex(parts: &[FlexTensor]) -> FlexTensor {
    let [n, _, h, w] = parts[0].shape().dims();
    let plane = h * w;
    let channels: Vec<usize> = parts.iter().map(|p| p.shape().dims::<4>()[1]).collect();
    let c: usize = channels.iter().sum();
    let dense: Vec<FlexTensor> = parts.iter().map(FlexTensor::to_contiguous).collect();
    let src: Vec<&[f32]> = dense.iter().map(|t| t.storage()).collect();
    // Output channel k of image b is channel k − (channels before part i) of part i.
    let mut owner = Vec::with_capacity(c);
    for (i, &ci) in channels.iter().enumerate() {
        owner.extend((0..ci).map(|k| (i, k)));
    }
    let mut out = vec![0f32; n * c * plane];
    out.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(j, dst)| {
            let (b, (i, k)) = (j / c, owner[j % c]);
            dst.copy_from_slice(&src[i][(b * channels[i] + k) * plane..][..plane]);
        });
    FlexTensor::from_data(TensorData::new(out, [n, c, h, w]))
}

#[cfg(test)]
mod tests {
    use burn::prelude::*;

    use crate::CpuBackend;

    /// The parallel copy gives exactly Burn's concatenation, views as inputs included.
    #[test]
    fn cat_channels_matches_burn_cat() {
        let device = Default::default();
        let make = |c: usize, s: f32| {
            let v: Vec<f32> = (0..2 * c * 3 * 4).map(|i| i as f32 * s).collect();
            Tensor::<CpuBackend, 1>::from_floats(v.as_slice(), &device).reshape([2, c, 3, 4])
        };
        let (a, b) = (make(3, 1.0), make(5, -0.5));
        // a strided view as the third part
        let c = make(4, 0.25)
            .swap_dims(2, 3)
            .swap_dims(2, 3)
            .narrow(1, 1, 2);
        let want = Tensor::cat(vec![a.clone(), b.clone(), c.clone()], 1);
        let got = super::cat_channels(vec![a, b, c]);
        assert_eq!(got.dims(), want.dims());
        assert_eq!(got.into_data(), want.into_data());
    }
}
