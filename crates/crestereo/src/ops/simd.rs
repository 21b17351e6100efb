//! Run-time processor features for the hand-written kernels.
//!
//! The crate is built for the x86-64 baseline (SSE2) so that one binary runs everywhere; the
//! hot element-wise kernels are compiled again for AVX2+FMA and for AVX-512
//! (`#[target_feature]`), and each call takes the widest copy the processor runs ([`isa`]).
//! The copies compute the same sums in the same order (Rust never contracts `a * b + c` into
//! an FMA by itself), so they agree bit for bit; the tests check each against the portable one.

use std::sync::OnceLock;

/// The instruction sets the hand-written kernels are compiled for, narrowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// The build's baseline (SSE2 on x86-64; whatever the target has elsewhere).
    Portable,
    /// AVX2 with FMA: 8 float32 lanes.
    Avx2,
    /// AVX-512 (F and VL): 16 float32 lanes.
    Avx512,
}

impl Isa {
    pub const ALL: [Isa; 3] = [Isa::Portable, Isa::Avx2, Isa::Avx512];

    /// The name `CRESTEREO_ISA` takes and `crestereo bench` prints.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// Whether this processor runs the copy compiled for `self` (each set includes the ones
    /// before it, so the supported sets are those up to [`Isa::best`]; a comparison, cheap
    /// enough for the kernels to check on every call).
    pub fn supported(self) -> bool {
        self <= Isa::best()
    }

    /// The widest set this processor runs (detected once).
    pub fn best() -> Isa {
        static BEST: OnceLock<Isa> = OnceLock::new();
        *BEST.get_or_init(|| {
            #[cfg(target_arch = "x86_64")]
            {
                let avx2 =
                    std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
                let avx512 = std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx512vl");
                match (avx2, avx512) {
                    (true, true) => return Isa::Avx512,
                    (true, false) => return Isa::Avx2,
                    _ => {}
                }
            }
            Isa::Portable
        })
    }

    /// The set a `CRESTEREO_ISA` value asks for (the widest supported when there is none), or
    /// why it cannot be had.
    pub fn parse(value: Option<&str>) -> Result<Isa, String> {
        let Some(value) = value else {
            return Ok(Isa::best());
        };
        let names = Isa::ALL.map(Isa::name).join(", ");
        let Some(isa) = Isa::ALL.into_iter().find(|i| i.name() == value.trim()) else {
            return Err(format!("CRESTEREO_ISA={value:?}: expected one of {names}"));
        };
        if !isa.supported() {
            return Err(format!(
                "CRESTEREO_ISA={value}: this processor does not have it (it has {})",
                Isa::best().name()
            ));
        }
        Ok(isa)
    }
}

/// The set the kernels take in this process: the widest the processor runs, or the one
/// `CRESTEREO_ISA` names (`portable`, `avx2`, `avx512`; to compare the copies on one machine).
/// Read once; an unknown or unsupported name is an error ([`isa_from_env`]).
pub fn isa() -> Isa {
    static CHOICE: OnceLock<Isa> = OnceLock::new();
    *CHOICE.get_or_init(|| isa_from_env().unwrap_or_else(|e| panic!("{e}")))
}

/// [`Isa::parse`] of `CRESTEREO_ISA`; binaries call this first, so that a bad value is a clear
/// error rather than a panic inside the first kernel.
pub fn isa_from_env() -> Result<Isa, String> {
    Isa::parse(std::env::var("CRESTEREO_ISA").ok().as_deref())
}

/// What the `gemm` crate (the matrix products, Flex's and ours) runs on this processor: it
/// chooses for itself, AVX-512 where the processor has it (the `x86-v4` feature this crate
/// turns on), whatever `CRESTEREO_ISA` says.
pub fn gemm_isa() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx512f") {
            return "avx512";
        }
        if Isa::best() >= Isa::Avx2 {
            return "avx2";
        }
    }
    "portable"
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

/// `dst[i] = f(a[i], b[i], c[i])` over equal-length slices, compiled for the widest
/// instruction set the processor has ([`isa`]), so that `f` built from the functions above
/// vectorises.
pub(crate) fn map3(
    dst: &mut [f32],
    a: &[f32],
    b: &[f32],
    c: &[f32],
    f: impl Fn(f32, f32, f32) -> f32,
) {
    map3_with(isa(), dst, a, b, c, f)
}

/// [`map3`] compiled for `set` (which the processor must support).
pub(crate) fn map3_with<F: Fn(f32, f32, f32) -> f32>(
    set: Isa,
    dst: &mut [f32],
    a: &[f32],
    b: &[f32],
    c: &[f32],
    f: F,
) {
    assert!(set.supported(), "{} on a processor without it", set.name());
    let n = dst.len();
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn avx2<F: Fn(f32, f32, f32) -> f32>(d: &mut [f32], a: &[f32], b: &[f32], c: &[f32], f: F) {
        map3_body(d, a, b, c, f)
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
    fn avx512<F: Fn(f32, f32, f32) -> f32>(d: &mut [f32], a: &[f32], b: &[f32], c: &[f32], f: F) {
        map3_body(d, a, b, c, f)
    }
    match set {
        // SAFETY: the processor supports the set (asserted above).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { avx512(dst, a, b, c, f) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { avx2(dst, a, b, c, f) },
        _ => map3_body(dst, a, b, c, f),
    }
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

    /// Every copy of `map3` this processor runs gives the portable copy's bits (the GRU
    /// gates' formulas, over lengths that leave every kind of remainder).
    #[test]
    fn map3_copies_agree_with_the_portable_one() {
        let gate = |z: f32, h: f32, q: f32| {
            let z = super::sigmoid(z);
            (1.0 - z) * h + z * super::tanh(q)
        };
        let mut tested = Vec::new();
        for set in super::Isa::ALL.into_iter().filter(|s| s.supported()) {
            for n in [0, 1, 7, 8, 15, 16, 17, 33, 1000, 4099] {
                let v = |k: usize| -> Vec<f32> {
                    (0..n)
                        .map(|i| ((i * 37 + k * 11) % 101) as f32 * 0.17 - 8.5)
                        .collect()
                };
                let (a, b, c) = (v(1), v(2), v(3));
                let (mut want, mut got) = (vec![0f32; n], vec![0f32; n]);
                super::map3_with(super::Isa::Portable, &mut want, &a, &b, &c, gate);
                super::map3_with(set, &mut got, &a, &b, &c, gate);
                let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&want), "{} copy, length {n}", set.name());
            }
            tested.push(set.name());
        }
        eprintln!("map3 copies checked: {tested:?}");
    }

    /// `CRESTEREO_ISA` names a set, refuses a name it does not know (listing the ones it
    /// takes), and never takes a set the processor lacks.
    #[test]
    fn isa_values_are_parsed_and_checked() {
        use super::Isa;
        assert_eq!(Isa::parse(None), Ok(Isa::best()));
        for set in Isa::ALL {
            let got = Isa::parse(Some(set.name()));
            if set <= Isa::best() {
                assert_eq!(got, Ok(set));
            } else {
                let e = got.expect_err("a set this processor lacks");
                assert!(e.contains("does not have it"), "{e}");
            }
        }
        assert_eq!(
            Isa::parse(Some(" avx2 ")).ok(),
            Isa::parse(Some("avx2")).ok()
        );
        let e = Isa::parse(Some("AVX-512")).expect_err("not a name");
        assert_eq!(
            e,
            "CRESTEREO_ISA=\"AVX-512\": expected one of portable, avx2, avx512"
        );
        assert!(Isa::Portable.supported() && Isa::best().supported());
    }
}
