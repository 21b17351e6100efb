//! Whole-network checks against the reference fixtures, generic over the backend: the Flex
//! tests (`parity.rs`, `gradients.rs`, `composed_ops.rs`) and the Vulkan tests
//! (`crestereo-train/tests/vulkan.rs`) run the same code at the same bounds.

use burn::prelude::*;
use burn::tensor::backend::AutodiffBackend;
use crestereo::sequence_loss;
use crestereo::weights::named_gradients;

use super::*;

/// The values of an intermediate the forward pass recorded.
fn recorded<B: Backend, const D: usize>(t: &Option<Tensor<B, D>>) -> Vec<f32> {
    values(t.clone().expect("recorded by the forward pass"))
}

pub fn train_forward_intermediates_predictions_and_loss<B: Backend>(device: &B::Device) {
    let m = model::<B>(device);
    let left = tensor::<B, 4>(&npy("train_b2_64x128/left.npy"), device);
    let right = tensor::<B, 4>(&npy("train_b2_64x128/right.npy"), device);
    let mut trace = Recorder::default();
    let preds = m.forward_observed(left, right, 10, None, &mut trace);
    assert_eq!(preds.len(), 20);

    let tol = 1e-4;
    let t = "train_b2_64x128";
    // Each intermediate against the fixture file of its name.
    let named = [
        ("fnet_fmap1", recorded(&trace.fmap1)),
        ("fnet_fmap2", recorded(&trace.fmap2)),
        ("pos_encoding_pe", recorded(&trace.pos_encoding)),
        ("conv_offset_16_raw", recorded(&trace.conv_offset_16_raw)),
        ("conv_offset_8_raw", recorded(&trace.conv_offset_8_raw)),
        (
            "selfatt_out_left_tokens",
            recorded(&trace.selfatt_left_tokens),
        ),
        (
            "selfatt_out_right_tokens",
            recorded(&trace.selfatt_right_tokens),
        ),
        (
            "crossatt_out_left_tokens_call0",
            recorded(&trace.crossatt_left_tokens_call0),
        ),
        (
            "crossatt_out_right_tokens_call0",
            recorded(&trace.crossatt_right_tokens_call0),
        ),
    ];
    for (name, got) in &named {
        check(name, got, &npy(&format!("{t}/{name}.npy")).data, tol);
    }
    assert_eq!(trace.corr.len(), 20);
    let mut worst = 0f32;
    for i in 0..20 {
        let named = [
            (format!("corr/{i:02}"), values(trace.corr[i].clone())),
            (
                format!("update/{i:02}_delta_flow"),
                values(trace.delta_flow[i].clone()),
            ),
            (
                format!("update/{i:02}_up_mask"),
                values(trace.up_mask[i].clone()),
            ),
        ];
        for (name, got) in &named {
            let want = npy(&format!("{t}/{name}.npy")).data;
            worst = worst.max(check(name, got, &want, tol));
        }
        let net = fixtures().join(format!("{t}/update/{i:02}_net.npy"));
        if net.exists() {
            let r = stereo_io::read_npy(&net).unwrap();
            worst = worst.max(check(
                &format!("update/{i:02}_net"),
                &values(trace.net[i].clone()),
                &r.data,
                tol,
            ));
        }
    }
    println!("worst scaled intermediate error over corr/update: {worst:.3e}");

    // predictions
    let reference = npy(&format!("{t}/preds.npy"));
    assert_eq!(reference.shape, vec![20, 2, 2, 64, 128]);
    let per = 2 * 2 * 64 * 128;
    let mut worst_pred = 0f32;
    for (i, p) in preds.iter().enumerate() {
        let (e, _) = max_err(&values(p.clone()), &reference.data[i * per..(i + 1) * per]);
        worst_pred = worst_pred.max(e);
    }
    println!("predictions: max|err| over all 20 = {worst_pred:.3e}");
    assert!(worst_pred <= 1e-3, "prediction error {worst_pred:e}");

    // loss, γ = 0.8 (released code) against the fixture, and γ = 0.9 (paper) against the
    // same formula evaluated in f64 on the reference predictions
    let disp_a = npy(&format!("{t}/gt_disp.npy"));
    let valid_a = npy(&format!("{t}/valid.npy"));
    let [n, h, w] = [2usize, 64, 128];
    assert_eq!(disp_a.data.len(), n * h * w);
    assert_eq!(valid_a.data.len(), n * h * w);
    let disp = Tensor::<B, 3>::from_data(TensorData::new(disp_a.data.clone(), [n, h, w]), device);
    let valid = Tensor::<B, 3>::from_data(TensorData::new(valid_a.data.clone(), [n, h, w]), device);
    let fixture_loss = npy(&format!("{t}/loss.npy")).data[0] as f64;
    for gamma in [0.8f64, 0.9] {
        let ours = sequence_loss(&preds, disp.clone(), valid.clone(), gamma)
            .into_scalar()
            .elem::<f64>();
        let mut reference_loss = 0f64;
        for i in 0..20 {
            let mut s = 0f64;
            for b in 0..n {
                for c in 0..2 {
                    for px in 0..h * w {
                        let pred = reference.data[i * per + (b * 2 + c) * h * w + px] as f64;
                        let gt = if c == 0 {
                            disp_a.data[b * h * w + px] as f64
                        } else {
                            0.0
                        };
                        s += valid_a.data[b * h * w + px] as f64 * (pred - gt).abs();
                    }
                }
            }
            reference_loss += gamma.powi(19 - i as i32) * s / (n * 2 * h * w) as f64;
        }
        if gamma == 0.8 {
            assert!(
                (reference_loss - fixture_loss).abs() / fixture_loss < 1e-5,
                "fixture loss recomputation"
            );
            let rel = (ours - fixture_loss).abs() / fixture_loss;
            println!("loss γ=0.8: ours {ours:.7} reference {fixture_loss:.7} rel.err {rel:.3e}");
            assert!(rel <= 1e-5, "loss relative error {rel:e}");
        } else {
            let rel = (ours - reference_loss).abs() / reference_loss;
            println!(
                "loss γ=0.9: ours {ours:.7} reference-preds {reference_loss:.7} rel.err {rel:.3e}"
            );
            assert!(rel <= 1e-5, "loss (γ=0.9) relative error {rel:e}");
        }
    }
}

pub fn eval_two_pass_cascade<B: Backend>(device: &B::Device) {
    let m = model::<B>(device);
    let e = "eval_cascade_1x128x192";
    let left = tensor::<B, 4>(&npy(&format!("{e}/left.npy")), device);
    let right = tensor::<B, 4>(&npy(&format!("{e}/right.npy")), device);
    // pass 1 on the ×½ pair, no init
    let l2 = crestereo::resize_bilinear_align_corners(left.clone(), [64, 96]);
    let r2 = crestereo::resize_bilinear_align_corners(right.clone(), [64, 96]);
    check(
        "left_dw2",
        &values(l2.clone()),
        &npy(&format!("{e}/left_dw2.npy")).data,
        1e-4,
    );
    let pred_dw2 = m.forward(l2, r2, 20, None).pop().unwrap();
    let (err_dw2, _) = max_err(
        &values(pred_dw2.clone()),
        &npy(&format!("{e}/pred_dw2.npy")).data,
    );
    println!("pred_dw2: max|err| {err_dw2:.3e}");
    // pass 2 at full size, initialised, 1/4 level only
    let pred_full = m
        .forward(left.clone(), right.clone(), 20, Some(pred_dw2))
        .pop()
        .unwrap();
    let (err_full, _) = max_err(
        &values(pred_full.clone()),
        &npy(&format!("{e}/pred_full.npy")).data,
    );
    println!("pred_full: max|err| {err_full:.3e}");
    assert!(err_dw2 <= 1e-3 && err_full <= 1e-3);
    // the library cascade gives the same result
    let cascade = crestereo::infer::cascade(
        &m,
        left.clone(),
        right.clone(),
        crestereo::InferenceOptions {
            iters: 20,
            stages: 2,
        },
    );
    let (err_cascade, _) = max_err(&values(cascade), &npy(&format!("{e}/pred_full.npy")).data);
    println!("cascade(): max|err| {err_cascade:.3e}");
    assert!(err_cascade <= 1e-3);
    // single pass without init
    let single = m.forward(left, right, 20, None).pop().unwrap();
    let (err_single, _) = max_err(
        &values(single),
        &npy(&format!("{e}/pred_single_pass_no_init.npy")).data,
    );
    println!("pred_single_pass_no_init: max|err| {err_single:.3e}");
    assert!(err_single <= 1e-3);
}

/// Conv biases directly followed by an instance norm: their exact gradient is zero (the norm
/// removes any per-channel constant), so the reference holds only float noise (~1e-8) there.
fn is_bias_before_instance_norm(name: &str) -> bool {
    name.starts_with("fnet.") && name.ends_with(".bias") && name != "fnet.conv2.bias"
}

pub struct Worst {
    pub cos: (f64, String),
    pub rel: (f64, String),
    pub zero: (f64, String),
}

/// Casts every float parameter to float64, each still a leaf of the autodiff graph.
struct ToFloat64;

impl<B: AutodiffBackend> burn::module::ModuleMapper<B> for ToFloat64 {
    fn map_float<const D: usize>(
        &mut self,
        param: burn::module::Param<Tensor<B, D>>,
    ) -> burn::module::Param<Tensor<B, D>> {
        param.map(|t| {
            Tensor::from_inner(t.inner().cast(burn::tensor::FloatDType::F64)).require_grad()
        })
    }
}

/// d loss / d parameter of the train fixture against `grads_official_semantics.npz`; with
/// `float64`, the whole module and its inputs are cast to float64 first (no rounding-level
/// ReLU-mask flips: the gradients of exact arithmetic to ~1e-5).
pub fn gradients<B: AutodiffBackend>(device: &B::Device, float64: bool) -> Worst {
    use burn::module::Module;
    let mut m = crestereo::CREStereoConfig::new().init::<B>(device);
    crestereo::weights::load_pytorch(&mut m, fixtures().join("weights_seed0.pt"), false).unwrap();
    let dtype = if float64 {
        m = m.map(&mut ToFloat64);
        burn::tensor::DType::F64
    } else {
        burn::tensor::DType::F32
    };
    let t = "train_b2_64x128";
    let input = |name: &str| tensor::<B, 4>(&npy(&format!("{t}/{name}.npy")), device).cast(dtype);
    let (left, right) = (input("left"), input("right"));
    let disp = npy(&format!("{t}/gt_disp.npy"));
    let valid = npy(&format!("{t}/valid.npy"));
    let disp =
        Tensor::<B, 3>::from_data(TensorData::new(disp.data, [2, 64, 128]), device).cast(dtype);
    let valid =
        Tensor::<B, 3>::from_data(TensorData::new(valid.data, [2, 64, 128]), device).cast(dtype);
    let preds = m.forward(left, right, 10, None);
    let loss = sequence_loss(&preds, disp, valid, 0.8);
    let grads = loss.backward();
    let ours = named_gradients(&m, &grads);
    let reference =
        stereo_io::read_npz(&fixtures().join(format!("{t}/grads_official_semantics.npz"))).unwrap();
    assert_eq!(reference.len(), 94);
    assert_eq!(ours.len(), 94);

    let mut worst_cos = (1.0f64, String::new());
    let mut worst_rel = (0.0f64, String::new());
    let mut worst_zero = (0.0f64, String::new());
    for (name, r) in &reference {
        let o = ours
            .iter()
            .find(|g| &g.name == name)
            .unwrap_or_else(|| panic!("no gradient for {name}"));
        assert_eq!(o.shape, r.shape, "{name}: shape");
        let (mut dot, mut oo, mut rr, mut dd) = (0f64, 0f64, 0f64, 0f64);
        for (a, b) in o.data.iter().zip(&r.data) {
            let (a, b) = (*a as f64, *b as f64);
            assert!(a.is_finite(), "{name}: non-finite gradient");
            dot += a * b;
            oo += a * a;
            rr += b * b;
            dd += (a - b) * (a - b);
        }
        if is_bias_before_instance_norm(name) {
            // exact gradient is 0: both sides must be at the float-noise floor
            let norm = oo.sqrt();
            println!(
                "{name:<45} |g| ours {norm:.2e}  reference {:.2e}  (exactly zero in exact arithmetic)",
                rr.sqrt()
            );
            assert!(
                norm < 1e-5 && rr.sqrt() < 1e-5,
                "{name}: gradient should vanish"
            );
            if norm > worst_zero.0 {
                worst_zero = (norm, name.clone());
            }
            continue;
        }
        let cos = dot / (oo.sqrt() * rr.sqrt()).max(1e-30);
        let rel = dd.sqrt() / rr.sqrt().max(1e-30);
        println!(
            "{name:<45} cos {cos:.8}  rel.L2 {rel:.3e}  |g| {:.3e}",
            rr.sqrt()
        );
        if cos < worst_cos.0 {
            worst_cos = (cos, name.clone());
        }
        if rel > worst_rel.0 {
            worst_rel = (rel, name.clone());
        }
    }
    println!(
        "float64={float64}: worst cosine {:.8} ({}), worst relative L2 {:.3e} ({}), largest vanishing-gradient norm {:.2e} ({})",
        worst_cos.0, worst_cos.1, worst_rel.0, worst_rel.1, worst_zero.0, worst_zero.1
    );
    Worst {
        cos: worst_cos,
        rel: worst_rel,
        zero: worst_zero,
    }
}

/// Every gradient direction within cosine 0.9999 of the reference, relative L2 within
/// `max_rel_l2`, and the gradients that vanish in exact arithmetic below 1e-6.
pub fn assert_gradients(w: &Worst, max_rel_l2: f64) {
    assert!(w.cos.0 >= 0.9999, "cosine {} for {}", w.cos.0, w.cos.1);
    assert!(
        w.rel.0 <= max_rel_l2,
        "relative L2 {} for {}",
        w.rel.0,
        w.rel.1
    );
    assert!(
        w.zero.0 < 1e-6,
        "vanishing gradient {} for {}",
        w.zero.0,
        w.zero.1
    );
}

/// The bounds of the all-float32 gradient path (see `gradients.rs`): relative L2 ≤ 2e-2.
pub fn assert_float32_gradients(w: &Worst) {
    assert_gradients(w, 2e-2);
}
