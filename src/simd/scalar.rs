//! Portable kernels: the reference every vectorised kernel is tested against.

/// `|a & b|`: bits set in both.
#[inline(always)]
pub fn and_popcount(a: &[u64], b: &[u64]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x & y).count_ones()).sum()
}
