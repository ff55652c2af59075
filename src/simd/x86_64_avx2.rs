//! AVX2 kernels (x86-64). Callers check [`super::Features`] first.

/// `|a & b|` with AVX2 + POPCNT code generation.
///
/// # Safety
/// The CPU must support AVX2 and POPCNT.
#[target_feature(enable = "avx2,popcnt")]
pub unsafe fn and_popcount(a: &[u64], b: &[u64]) -> u32 {
    super::scalar::and_popcount(a, b)
}
