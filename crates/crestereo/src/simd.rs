//! Run-time processor features for the hand-written kernels.
//!
//! The crate is built for the x86-64 baseline (SSE2) so that one binary runs everywhere; the
//! hot element-wise kernels are compiled a second time with AVX2 and FMA enabled
//! (`#[target_feature]`) and take that copy when the processor has them.

/// Whether this processor has AVX2 and FMA (checked once, then cached by std).
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_avx2() -> bool {
    std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
}

/// `e^x` for float32 without a library call, so that loops over it vectorise: `2^n · e^r` with
/// `n = round(x / ln 2)` and `e^r` (|r| ≤ ln 2 / 2) by its Taylor polynomial to degree 7
/// (truncation ≤ 6e-9 relative); inputs clamped to [−87, 88], where `2^n` stays a normal float.
/// Within a few float32 ulps of `f32::exp`.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.0, 88.0);
    let n = (x * std::f32::consts::LOG2_E).round();
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.0 / 5040.0;
    for c in [
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p * r + c;
    }
    p * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// The logistic function by [`exp`] (branch-free: the clamp keeps both tails exact).
#[inline(always)]
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// `tanh x = 1 − 2 / (e^{2x} + 1)` by [`exp`] (absolute error ~1e-7 near 0).
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    1.0 - 2.0 / (exp(2.0 * x) + 1.0)
}

/// `dst[i] = f(a[i], b[i], c[i])` over equal-length slices, compiled for AVX2 + FMA when the
/// processor has them (so that `f` built from the functions above vectorises).
pub(crate) fn map3(
    dst: &mut [f32],
    a: &[f32],
    b: &[f32],
    c: &[f32],
    f: impl Fn(f32, f32, f32) -> f32,
) {
    let n = dst.len();
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the processor supports AVX2 and FMA (checked just above).
        return unsafe { map3_avx2(dst, a, b, c, f) };
    }
    map3_body(dst, a, b, c, f)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn map3_avx2(dst: &mut [f32], a: &[f32], b: &[f32], c: &[f32], f: impl Fn(f32, f32, f32) -> f32) {
    map3_body(dst, a, b, c, f)
}

#[inline(always)]
fn map3_body(dst: &mut [f32], a: &[f32], b: &[f32], c: &[f32], f: impl Fn(f32, f32, f32) -> f32) {
    for (((d, &a), &b), &c) in dst.iter_mut().zip(a).zip(b).zip(c) {
        *d = f(a, b, c);
    }
}

#[cfg(test)]
mod tests {
    /// The vectorisable exp, sigmoid and tanh against the standard library's over their range.
    #[test]
    fn exp_sigmoid_tanh_match_the_standard_library() {
        let mut worst = [0f32; 3];
        for i in -200_000..=200_000 {
            let x = i as f32 * 4.4e-4;
            // Below −87 the clamp holds e^x at e^−87 (both gates saturate long before).
            let rel = if x >= -87.0 {
                (super::exp(x) - x.exp()).abs() / x.exp()
            } else {
                0.0
            };
            let sig = (super::sigmoid(x) - 1.0 / (1.0 + (-x).exp())).abs();
            let tanh = (super::tanh(x) - x.tanh()).abs();
            for (w, e) in worst.iter_mut().zip([rel, sig, tanh]) {
                *w = w.max(e);
            }
        }
        assert!(worst[0] < 1e-6, "exp: worst relative error {}", worst[0]);
        assert!(
            worst[1] < 2e-7,
            "sigmoid: worst absolute error {}",
            worst[1]
        );
        assert!(worst[2] < 3e-7, "tanh: worst absolute error {}", worst[2]);
        assert!(super::sigmoid(-1e4) < 1e-37 && super::sigmoid(1e4) == 1.0);
        assert_eq!((super::tanh(-1e4), super::tanh(1e4)), (-1.0, 1.0));
    }
}
