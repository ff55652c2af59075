//! AVX-512 kernels (x86-64). Callers check [`super::Features`] first.

/// `|a & b|` with wide u64 lanes, so that the sum vectorises with vpopcntq.
///
/// # Safety
/// The CPU must support AVX-512 F and VPOPCNTDQ, and POPCNT.
#[target_feature(enable = "avx512f,avx512vpopcntdq,popcnt")]
pub unsafe fn and_popcount(a: &[u64], b: &[u64]) -> u32 {
    let s: u64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x & y).count_ones() as u64)
        .sum();
    s as u32
}

/// [`super::scalar::compat_row`] compiled for AVX-512 F+BW+VL (and AVX2 + FMA).
///
/// # Safety
/// The CPU must support AVX-512 F, BW and VL, AVX2 and FMA.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma")]
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

/// `out[k] = |a & rows[k]|` for rows of a length that is a multiple of 8 words: each 512-bit
/// chunk of `a` is loaded once for up to four rows.
///
/// # Safety
/// The CPU must support AVX-512 F and VPOPCNTDQ; `a` and every row have the same length, a
/// multiple of 8; `out` is at least as long as `rows`.
#[target_feature(enable = "avx512f,avx512vpopcntdq")]
pub unsafe fn and_popcount_many(a: &[u64], rows: &[&[u64]], out: &mut [u32]) {
    debug_assert!(a.len().is_multiple_of(8) && rows.iter().all(|r| r.len() == a.len()));
    let mut k = 0;
    while k + 4 <= rows.len() {
        let r = [rows[k], rows[k + 1], rows[k + 2], rows[k + 3]];
        out[k..k + 4].copy_from_slice(&and_popcount_n::<4>(a, r));
        k += 4;
    }
    for (r, o) in rows[k..].iter().zip(&mut out[k..]) {
        *o = and_popcount_n::<1>(a, [r])[0];
    }
}

/// N rows against `a` with N accumulators held in registers.
#[target_feature(enable = "avx512f,avx512vpopcntdq")]
#[inline]
unsafe fn and_popcount_n<const N: usize>(a: &[u64], rows: [&[u64]; N]) -> [u32; N] {
    use std::arch::x86_64::*;
    let len = a.len();
    let mut acc = [_mm512_setzero_si512(); N];
    let mut w = 0;
    while w < len {
        // SAFETY: w + 8 <= len for every slice (lengths are equal multiples of 8).
        let x = _mm512_loadu_si512(a.as_ptr().add(w) as *const __m512i);
        for q in 0..N {
            let y = _mm512_loadu_si512(rows[q].as_ptr().add(w) as *const __m512i);
            acc[q] = _mm512_add_epi64(acc[q], _mm512_popcnt_epi64(_mm512_and_si512(x, y)));
        }
        w += 8;
    }
    let mut out = [0u32; N];
    for q in 0..N {
        out[q] = _mm512_reduce_add_epi64(acc[q]) as u32;
    }
    out
}
