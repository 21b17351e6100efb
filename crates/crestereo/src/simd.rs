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
