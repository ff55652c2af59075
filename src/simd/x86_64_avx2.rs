//! AVX2 kernels (x86-64). Callers check [`super::Features`] first.

/// `|a & b|` with AVX2 + POPCNT code generation.
///
/// # Safety
/// The CPU must support AVX2 and POPCNT.
#[target_feature(enable = "avx2,popcnt")]
pub unsafe fn and_popcount(a: &[u64], b: &[u64]) -> u32 {
    super::scalar::and_popcount(a, b)
}

/// [`super::scalar::compat_row`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub unsafe fn compat_row(
    p: super::PairColumns,
    i: usize,
    d: f32,
    nms: f32,
    w0: usize,
    words: usize,
    rows: (&mut [u64], &mut [u64], &mut [u64]),
    vals: &mut Vec<(u32, f32)>,
) {
    super::scalar::compat_row(p, i, d, nms, w0, words, rows, vals)
}
