//! [`MatmulOps`] for CubeCL backends: CubeCL's unit matmul with one fixed tiling (the largest
//! tile the device allows), float32 in global memory, shared memory and registers, and the
//! `Fusion<B>` wrapper that records each product as one custom operation of the fusion stream.

use burn::tensor::DType;
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::kernel::matmul::init_matmul_output;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{BoolElement, CubeBackend, CubeRuntime, FloatElement, IntElement};
use cubek::matmul::definition::{MatmulElems, MatmulGlobalElems};
use cubek::matmul::launch::{Strategy, launch_ref};
use cubek::matmul::routines::simple_unit::SimpleUnitSelectionArgs;
use cubek::matmul::routines::{BlueprintStrategy, TileSizeSelection};
use cubek::std::InputBinding;

use super::MatmulOps;

/// The one strategy: a unit matmul (no tensor cores, so no TF32), largest tiles.
fn fixed_strategy() -> Strategy {
    Strategy::SimpleUnit(BlueprintStrategy::Inferred(SimpleUnitSelectionArgs {
        tile_size: TileSizeSelection::MaxTileSize,
    }))
}

fn f32_input<R: CubeRuntime>(t: CubeTensor<R>) -> CubeTensor<R> {
    assert_eq!(
        t.dtype,
        DType::F32,
        "the float32 matmul takes float32 tensors, got {:?}",
        t.dtype
    );
    // One layout per operand keeps the kernel set small (no variant per stride pattern).
    into_contiguous(t)
}

/// `lhs · rhs` on `R` with the fixed strategy; the naive kernel where the unit matmul cannot
/// be set up for a shape (both are plain float32 arithmetic).
pub(super) fn f32_matmul_cube<R: CubeRuntime>(
    lhs: CubeTensor<R>,
    rhs: CubeTensor<R>,
) -> CubeTensor<R> {
    let (lhs, rhs) = (f32_input(lhs), f32_input(rhs));
    let out = init_matmul_output(&lhs, &rhs, DType::F32);
    let f32_type = f32::as_type_native_unchecked().storage_type();
    let globals = MatmulGlobalElems {
        lhs: f32_type,
        rhs: f32_type,
        out: f32_type,
    };
    let launch = |strategy: &Strategy| {
        let mut dtypes = MatmulElems::from_globals(&globals);
        launch_ref(
            strategy,
            &out.client,
            InputBinding::new(lhs.clone().binding(), f32_type),
            InputBinding::new(rhs.clone().binding(), f32_type),
            out.clone().binding(),
            &mut dtypes,
        )
    };
    if let Err(unit) = launch(&fixed_strategy()) {
        launch(&Strategy::Naive).unwrap_or_else(|naive| {
            panic!("float32 matmul: the unit kernel ({unit:?}) and the naive one ({naive:?}) both refused the shapes")
        });
    }
    out
}

impl<R: CubeRuntime, F: FloatElement, I: IntElement, BT: BoolElement> MatmulOps
    for CubeBackend<R, F, I, BT>
{
    fn f32_matmul(lhs: CubeTensor<R>, rhs: CubeTensor<R>) -> CubeTensor<R> {
        f32_matmul_cube(lhs, rhs)
    }
}

mod fusion {
    //! `Fusion<B>`: each product is one custom operation in the fusion stream; it runs the inner
    //! backend's kernel when the stream executes.

    use burn::tensor::ops::FloatTensor;
    use burn::tensor::{Shape, TensorMetadata};
    use burn_fusion::stream::{Operation, OperationStreams};
    use burn_fusion::{Fusion, FusionBackend, FusionRuntime};
    use burn_ir::{CustomOpIr, HandleContainer, OperationIr, TensorIr};

    use super::super::MatmulOps;

    type Handles<B> =
        HandleContainer<<<B as FusionBackend>::FusionRuntime as FusionRuntime>::FusionHandle>;

    #[derive(Clone, Debug)]
    struct MatmulOp<B> {
        desc: CustomOpIr,
        _backend: core::marker::PhantomData<B>,
    }

    impl<B: FusionBackend + MatmulOps> Operation<B::FusionRuntime> for MatmulOp<B> {
        fn execute(&self, handles: &mut Handles<B>) {
            let lhs = handles.get_float_tensor::<B>(&self.desc.inputs[0]);
            let rhs = handles.get_float_tensor::<B>(&self.desc.inputs[1]);
            let out = B::f32_matmul(lhs, rhs);
            handles.register_float_tensor::<B>(&self.desc.outputs[0].id, out);
        }
    }

    impl<B: FusionBackend + MatmulOps> MatmulOps for Fusion<B> {
        fn f32_matmul(lhs: FloatTensor<Self>, rhs: FloatTensor<Self>) -> FloatTensor<Self> {
            let client = lhs.client.clone();
            let dtype = lhs.dtype;
            // (…, M, K) × (…, K, N) → (…, M, N); the batch dimensions are equal (see `matmul`).
            let mut dims: Vec<usize> = TensorMetadata::shape(&lhs).as_slice().into();
            let n = *TensorMetadata::shape(&rhs)
                .as_slice()
                .last()
                .expect("rank ≥ 2");
            *dims.last_mut().expect("rank ≥ 2") = n;
            let streams = OperationStreams::with_inputs([&lhs, &rhs]);
            let out = TensorIr::uninit(client.create_empty_handle(), Shape::from(dims), dtype);
            let inputs = [lhs.into_ir(), rhs.into_ir()];
            let desc = CustomOpIr::new("crestereo_f32_matmul", &inputs, &[out]);
            client
                .register(
                    streams,
                    OperationIr::Custom(desc.clone()),
                    MatmulOp::<B> {
                        desc,
                        _backend: core::marker::PhantomData,
                    },
                )
                .remove(0)
        }
    }
}
