//! [`AgclOps`] for the Flex CPU backend: the kernels of `kernels.rs` on the tensors' storage.

use burn::backend::Flex;
use burn::backend::flex::FlexTensor;
use burn::tensor::{DType, TensorData, TensorMetadata};

use super::kernels::{self, Dims};
use super::layout::{channel_last, from_channel_last};
use super::{AgclOps, CorrSpec};

/// Contiguous float32 copy (or the tensor itself when it already is).
fn dense(t: &FlexTensor) -> FlexTensor {
    assert_eq!(
        t.dtype(),
        DType::F32,
        "AGCL kernels run in float32, got {:?}",
        t.dtype()
    );
    t.to_contiguous()
}

fn nchw(data: Vec<f32>, shape: [usize; 4]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(data, shape))
}

fn dims(t: &FlexTensor) -> Dims {
    let s = t.shape();
    Dims {
        n: s[0],
        c: s[1],
        h: s[2],
        w: s[3],
    }
}

impl AgclOps for Flex {
    fn agcl_offset_corr(
        left: FlexTensor,
        right: FlexTensor,
        flow: FlexTensor,
        offset: FlexTensor,
        spec: CorrSpec,
    ) -> FlexTensor {
        let d = dims(&left);
        let (l, r) = (channel_last(&left), channel_last(&right));
        let (f, o) = (dense(&flow), dense(&offset));
        let out = kernels::offset_corr_forward(
            l.storage(),
            r.storage(),
            f.storage(),
            o.storage(),
            d,
            spec,
        );
        from_channel_last(out, d, spec.groups * spec.candidates())
    }

    fn agcl_offset_corr_backward(
        left: FlexTensor,
        right: FlexTensor,
        flow: FlexTensor,
        offset: FlexTensor,
        grad: FlexTensor,
        spec: CorrSpec,
        need: [bool; 4],
    ) -> [Option<FlexTensor>; 4] {
        let d = dims(&left);
        let (l, r) = (channel_last(&left), channel_last(&right));
        let (f, o, g) = (dense(&flow), dense(&offset), dense(&grad));
        let grads = kernels::offset_corr_backward(
            l.storage(),
            r.storage(),
            f.storage(),
            o.storage(),
            g.storage(),
            d,
            spec,
            need[1],
        );
        let k2 = 2 * spec.candidates();
        [
            need[0].then(|| from_channel_last(grads.left, d, d.c)),
            need[1].then(|| from_channel_last(grads.right, d, d.c)),
            need[2].then(|| from_channel_last(grads.flow, d, 2)),
            need[3].then(|| from_channel_last(grads.offset, d, k2)),
        ]
    }

    fn agcl_warp(right: FlexTensor, flow: FlexTensor) -> FlexTensor {
        let d = dims(&right);
        let (r, f) = (dense(&right), dense(&flow));
        let out = kernels::warp_forward(r.storage(), f.storage(), d);
        nchw(out, [d.n, d.c, d.h, d.w])
    }

    fn agcl_warp_backward(
        right: FlexTensor,
        flow: FlexTensor,
        grad: FlexTensor,
        need: [bool; 2],
    ) -> [Option<FlexTensor>; 2] {
        let d = dims(&right);
        let (r, f, g) = (dense(&right), dense(&flow), dense(&grad));
        let (dr, df) = kernels::warp_backward(r.storage(), f.storage(), g.storage(), d, need);
        [
            need[0].then(|| nchw(dr, [d.n, d.c, d.h, d.w])),
            need[1].then(|| nchw(df, [d.n, 2, d.h, d.w])),
        ]
    }
}
