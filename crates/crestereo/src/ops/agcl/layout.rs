//! The channel-last buffers the CPU kernels read and write, to and from Flex's (N, C, H, W),
//! copied in parallel.
//!
//! Flex would do either change of layout as a strided view, and the first op to need the map
//! dense (the next convolution, or the gradient sum when a map gets gradients from two places)
//! would then copy it element by element on one thread while the other threads wait.

use burn::backend::flex::FlexTensor;
use burn::tensor::{DType, TensorData, TensorMetadata};
use rayon::prelude::*;

use super::kernels::Dims;

/// (N, C, H, W) → contiguous (N, H, W, C), as a buffer.
pub(super) fn channel_last(t: &FlexTensor) -> FlexTensor {
    assert_eq!(
        t.dtype(),
        DType::F32,
        "AGCL kernels run in float32, got {:?}",
        t.dtype()
    );
    let [n, c, h, w] = t.shape().dims();
    let t = t.to_contiguous();
    let src: &[f32] = t.storage();
    let mut out = vec![0f32; n * h * w * c];
    // One output row (w · c values) per task, read from c input rows.
    out.par_chunks_mut((w * c).max(1))
        .enumerate()
        .for_each(|(row, dst)| {
            let (b, y) = (row / h, row % h);
            for ch in 0..c {
                let line = &src[((b * c + ch) * h + y) * w..][..w];
                for (x, &v) in line.iter().enumerate() {
                    dst[x * c + ch] = v;
                }
            }
        });
    FlexTensor::from_data(TensorData::new(out, [n, h, w, c]))
}

/// A channel-last (N, H, W, C) buffer as a contiguous (N, C, H, W) tensor.
pub(super) fn from_channel_last(data: Vec<f32>, d: Dims, c: usize) -> FlexTensor {
    let plane = d.h * d.w;
    assert_eq!(
        data.len(),
        d.n * plane * c,
        "a channel-last buffer of {d:?} × {c}"
    );
    let mut out = vec![0f32; data.len()];
    // One output plane per task, a strided read of the channel-last image.
    out.par_chunks_mut(plane.max(1))
        .enumerate()
        .for_each(|(i, dst)| {
            let (b, ch) = (i / c, i % c);
            let image = &data[b * plane * c..][..plane * c];
            for (p, v) in dst.iter_mut().enumerate() {
                *v = image[p * c + ch];
            }
        });
    FlexTensor::from_data(TensorData::new(out, [d.n, c, d.h, d.w]))
}

#[cfg(test)]
mod tests {
    use burn::backend::flex::FlexTensor;
    use burn::tensor::{TensorData, TensorMetadata};

    use super::super::kernels::Dims;

    /// Both copies agree with Flex's own permutation, and undo each other.
    #[test]
    fn channel_last_copies_match_flex_permute() {
        let (n, c, h, w) = (2, 5, 3, 7);
        let values: Vec<f32> = (0..n * c * h * w).map(|i| i as f32 * 0.5 - 3.0).collect();
        let t = FlexTensor::from_data(TensorData::new(values.clone(), [n, c, h, w]));
        let last = super::channel_last(&t);
        let want = t.permute(&[0, 2, 3, 1]).to_contiguous();
        assert_eq!(last.shape().dims::<4>(), [n, h, w, c]);
        assert_eq!(last.storage::<f32>(), want.storage::<f32>());
        let back = super::from_channel_last(last.storage::<f32>().to_vec(), Dims { n, c, h, w }, c);
        assert!(back.is_contiguous());
        assert_eq!(back.storage::<f32>(), &values[..]);
    }
}
