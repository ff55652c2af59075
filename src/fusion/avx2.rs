//! AVX2 forms of the fusion's per-row loops (`calibrate::fast_exp`, `max_lanes`, `sum_lanes`,
//! the Noisy-AND rank key, the column maxima), written with intrinsics so they run 8 lanes
//! wide in every build: the dev profile (opt-level 1) does not vectorise loops, and these
//! loops are most of a re-fusion. Each lane does the operations of the scalar code in the
//! same order (no fused multiply-add; the selects keep the scalar comparisons' NaN rules), and
//! the lanes are reduced as the scalar code reduces its 8 accumulators, so every result is bit
//! for bit the scalar one (tested against it).
//!
//! Callers check `crate::simd::features().avx2` first.

// The scalar remainders index several slices with one position, as the scalar code does.
#![allow(clippy::needless_range_loop)]

use std::arch::x86_64::*;

use super::calibrate::fast_exp;

/// `calibrate::fast_exp` on 8 lanes.
///
/// # Safety
/// The CPU must support AVX2.
#[inline]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn fast_exp8(x: __m256) -> __m256 {
    let lo = _mm256_set1_ps(-87.336_54);
    let hi = _mm256_set1_ps(88.0);
    let magic = _mm256_set1_ps(12_582_912.0);
    let below = _mm256_cmp_ps::<_CMP_LT_OQ>(x, lo);
    let xc = _mm256_blendv_ps(x, lo, below);
    let xc = _mm256_blendv_ps(xc, hi, _mm256_cmp_ps::<_CMP_GT_OQ>(xc, hi));
    let t = _mm256_add_ps(
        _mm256_mul_ps(xc, _mm256_set1_ps(std::f32::consts::LOG2_E)),
        magic,
    );
    let n = _mm256_sub_ps(t, magic);
    let r = _mm256_add_ps(
        _mm256_sub_ps(xc, _mm256_mul_ps(n, _mm256_set1_ps(0.693_359_4))),
        _mm256_mul_ps(n, _mm256_set1_ps(2.121_944_4e-4)),
    );
    let mut p = _mm256_add_ps(
        _mm256_mul_ps(_mm256_set1_ps(1.987_569_1e-4), r),
        _mm256_set1_ps(1.398_199_9e-3),
    );
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(8.333_452e-3));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(4.166_579_6e-2));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(1.666_666_5e-1));
    p = _mm256_add_ps(_mm256_mul_ps(p, r), _mm256_set1_ps(0.5));
    let y = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(p, _mm256_mul_ps(r, r)), r),
        _mm256_set1_ps(1.0),
    );
    let ni = _mm256_sub_epi32(
        _mm256_castps_si256(t),
        _mm256_set1_epi32(12_582_912.0f32.to_bits() as i32),
    );
    let scale = _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_add_epi32(
        ni,
        _mm256_set1_epi32(127),
    )));
    _mm256_andnot_ps(below, _mm256_mul_ps(y, scale))
}

fn lanes(v: __m256) -> [f32; 8] {
    // SAFETY: __m256 and [f32; 8] have the same size; any bits are a valid f32.
    unsafe { std::mem::transmute::<__m256, [f32; 8]>(v) }
}

/// `max_lanes`' final fold: the 8 accumulators, then the remainder, first to last.
fn max_fold(acc: __m256, rem: &[f32]) -> f32 {
    let mut m = f32::NEG_INFINITY;
    for &v in lanes(acc).iter().chain(rem) {
        m = if v > m { v } else { m };
    }
    m
}

/// `out = src + bias`, then `max_lanes(out)`.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn add_max(out: &mut [f32], src: &[f32], bias: &[f32]) -> f32 {
    let n = out.len().min(src.len()).min(bias.len());
    let (out, src, bias) = (&mut out[..n], &src[..n], &bias[..n]);
    let full = n - n % 8;
    let mut acc = _mm256_set1_ps(f32::NEG_INFINITY);
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= full <= n for all three slices (unaligned loads and store).
        let v = _mm256_add_ps(
            _mm256_loadu_ps(src.as_ptr().add(k)),
            _mm256_loadu_ps(bias.as_ptr().add(k)),
        );
        _mm256_storeu_ps(out.as_mut_ptr().add(k), v);
        // max_lanes: acc = if v > acc { v } else { acc }
        acc = _mm256_max_ps(v, acc);
    }
    for k in full..n {
        out[k] = src[k] + bias[k];
    }
    max_fold(acc, &out[full..])
}

/// `x = fast_exp((x - mx) * it)` in place, then `sum_lanes(x)`.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn exp_sum(x: &mut [f32], mx: f32, it: f32) -> f32 {
    let n = x.len();
    let full = n - n % 8;
    let (vmx, vit) = (_mm256_set1_ps(mx), _mm256_set1_ps(it));
    let mut acc = _mm256_setzero_ps();
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= n.
        let p = x.as_mut_ptr().add(k);
        let e = fast_exp8(_mm256_mul_ps(_mm256_sub_ps(_mm256_loadu_ps(p), vmx), vit));
        _mm256_storeu_ps(p, e);
        acc = _mm256_add_ps(acc, e);
    }
    for v in &mut x[full..] {
        *v = fast_exp((*v - mx) * it);
    }
    lanes(acc).iter().sum::<f32>() + x[full..].iter().sum::<f32>()
}

/// `1 / sum_j fast_exp((row_j - mx) * it)` with 8 accumulators (the row-NN posterior of the
/// row's maximum `mx`), the row left as it is.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn inv_exp_sum(row: &[f32], mx: f32, it: f32) -> f32 {
    let n = row.len();
    let full = n - n % 8;
    let (vmx, vit) = (_mm256_set1_ps(mx), _mm256_set1_ps(it));
    let mut acc = _mm256_setzero_ps();
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= n.
        let v = _mm256_loadu_ps(row.as_ptr().add(k));
        acc = _mm256_add_ps(acc, fast_exp8(_mm256_mul_ps(_mm256_sub_ps(v, vmx), vit)));
    }
    let z = lanes(acc).iter().sum::<f32>()
        + row[full..]
            .iter()
            .map(|&v| fast_exp((v - mx) * it))
            .sum::<f32>();
    1.0 / z
}

/// `if p > 1 { 1 } else { p }` per lane.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn cap(p: __m256) -> __m256 {
    let one = _mm256_set1_ps(1.0);
    _mm256_blendv_ps(p, one, _mm256_cmp_ps::<_CMP_GT_OQ>(p, one))
}

/// The Noisy-AND rank keys of one row, `keys_j = odds_product(a_j * ia, b_j * ib)`.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn rank_keys(keys: &mut [f32], a: &[f32], b: &[f32], ia: f32, ib: f32) {
    let n = keys.len().min(a.len()).min(b.len());
    let full = n - n % 8;
    let (via, vib) = (_mm256_set1_ps(ia), _mm256_set1_ps(ib));
    let (one, zero) = (_mm256_set1_ps(1.0), _mm256_setzero_ps());
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= n for all three slices.
        let x = cap(_mm256_mul_ps(_mm256_loadu_ps(a.as_ptr().add(k)), via));
        let y = cap(_mm256_mul_ps(_mm256_loadu_ps(b.as_ptr().add(k)), vib));
        let p = _mm256_mul_ps(x, y);
        let q = _mm256_div_ps(
            p,
            _mm256_mul_ps(_mm256_sub_ps(one, x), _mm256_sub_ps(one, y)),
        );
        // if p > 0 { q } else { 0 } (NaN fails p > 0)
        let v = _mm256_and_ps(q, _mm256_cmp_ps::<_CMP_GT_OQ>(p, zero));
        _mm256_storeu_ps(keys.as_mut_ptr().add(k), v);
    }
    for k in full..n {
        keys[k] = super::fuse::noisy_and_rank_key(a[k] * ia, b[k] * ib);
    }
}

/// The column maxima of the keys and their row: where `keys_j > best_j`, `best_j = keys_j`
/// and `row_j = i`.
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn col_max(keys: &[f32], best: &mut [f32], row: &mut [u32], i: u32) {
    let n = keys.len().min(best.len()).min(row.len());
    let full = n - n % 8;
    let vi = _mm256_castsi256_ps(_mm256_set1_epi32(i as i32));
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= n for all three slices.
        let v = _mm256_loadu_ps(keys.as_ptr().add(k));
        let pb = best.as_mut_ptr().add(k);
        let pr = row.as_mut_ptr().add(k) as *mut f32;
        let b = _mm256_loadu_ps(pb);
        let better = _mm256_cmp_ps::<_CMP_GT_OQ>(v, b);
        _mm256_storeu_ps(pb, _mm256_blendv_ps(b, v, better));
        _mm256_storeu_ps(pr, _mm256_blendv_ps(_mm256_loadu_ps(pr), vi, better));
    }
    for k in full..n {
        let better = keys[k] > best[k];
        best[k] = if better { keys[k] } else { best[k] };
        row[k] = if better { i } else { row[k] };
    }
}

/// `max_lanes(x)` and, when it is > 0, the first position holding it (as `fused::first_eq`).
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn max_first_positive(x: &[f32]) -> Option<(usize, f32)> {
    let n = x.len();
    let full = n - n % 8;
    let mut acc = _mm256_set1_ps(f32::NEG_INFINITY);
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= n.
        acc = _mm256_max_ps(_mm256_loadu_ps(x.as_ptr().add(k)), acc);
    }
    let mx = max_fold(acc, &x[full..]);
    // NaN is not > 0
    let positive = mx > 0.0;
    if !positive {
        return None;
    }
    let vm = _mm256_set1_ps(mx);
    for k in (0..full).step_by(8) {
        // SAFETY: k + 8 <= n.
        let eq = _mm256_cmp_ps::<_CMP_EQ_OQ>(_mm256_loadu_ps(x.as_ptr().add(k)), vm);
        let bits = _mm256_movemask_ps(eq);
        if bits != 0 {
            return Some((k + bits.trailing_zeros() as usize, mx));
        }
    }
    x[full..]
        .iter()
        .position(|&v| v == mx)
        .map(|j| (full + j, mx))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::fusion::calibrate::{max_lanes, sum_lanes};

    /// Rows of every remainder length for 8 and 16 lanes, with the special values placed.
    pub(crate) fn rows(seed: u64) -> Vec<Vec<f32>> {
        let mut s = crate::testing::Lcg(seed);
        let mut next = || s.unit_f32();
        let mut out = Vec::new();
        for len in [0usize, 1, 7, 8, 9, 15, 16, 17, 24, 31, 64, 1001, 7133] {
            let mut r: Vec<f32> = (0..len).map(|_| next() * 2.0 - 1.0).collect();
            if len > 20 {
                r[2] = f32::NEG_INFINITY;
                r[4] = f32::NAN;
                r[6] = 1.0;
                r[9] = 1.5;
                r[11] = -1e30;
                r[13] = 0.0;
                r[17] = -200.0;
                r[len - 1] = f32::INFINITY;
            }
            out.push(r);
        }
        out
    }

    pub(crate) fn same(a: f32, b: f32) -> bool {
        a.to_bits() == b.to_bits() || a.is_nan() && b.is_nan()
    }

    #[test]
    fn every_kernel_gives_the_scalar_bits() {
        if !crate::simd::features().avx2 {
            return;
        }
        for (ri, row) in rows(5).into_iter().enumerate() {
            let n = row.len();
            let bias: Vec<f32> = (0..n)
                .map(|j| if j % 5 == 3 { f32::NEG_INFINITY } else { 0.0 })
                .collect();
            // add + max
            let mut out = vec![0.0; n];
            let m = unsafe { add_max(&mut out, &row, &bias) };
            let want: Vec<f32> = row.iter().zip(&bias).map(|(a, b)| a + b).collect();
            assert!(out.iter().zip(&want).all(|(a, b)| same(*a, *b)), "row {ri}");
            assert!(same(m, max_lanes(&want)), "row {ri}");
            // exp + sum, and the sum alone
            for (mx, it) in [(0.9f32, 10.0f32), (1.5, 1.0 / 0.12), (0.0, 100.0)] {
                let mut x = row.clone();
                let s = unsafe { exp_sum(&mut x, mx, it) };
                let e: Vec<f32> = row.iter().map(|&v| fast_exp((v - mx) * it)).collect();
                assert!(x.iter().zip(&e).all(|(a, b)| same(*a, *b)), "row {ri}");
                assert!(same(s, sum_lanes(&e)), "row {ri}");
                let inv = unsafe { inv_exp_sum(&row, mx, it) };
                let mut acc = [0.0f32; 8];
                let ch = row.chunks_exact(8);
                let rem = ch.remainder();
                for c in ch {
                    for k in 0..8 {
                        acc[k] += fast_exp((c[k] - mx) * it);
                    }
                }
                let z = acc.iter().sum::<f32>()
                    + rem.iter().map(|&v| fast_exp((v - mx) * it)).sum::<f32>();
                assert!(same(inv, 1.0 / z), "row {ri}");
            }
            // rank keys (posteriors above 1 and at 1 included)
            let b: Vec<f32> = row.iter().rev().map(|v| v.abs()).collect();
            let a: Vec<f32> = row.iter().map(|v| v.abs() * 1.2).collect();
            for (ia, ib) in [(1.0f32, 1.0f32), (0.7, 3.0), (f32::INFINITY, 0.5)] {
                let mut keys = vec![0.0; n];
                unsafe { rank_keys(&mut keys, &a, &b, ia, ib) };
                for j in 0..n {
                    let w = crate::fusion::fuse::noisy_and_rank_key(a[j] * ia, b[j] * ib);
                    assert!(same(keys[j], w), "row {ri} col {j}: {} vs {w}", keys[j]);
                }
            }
            // column maxima
            let (mut best, mut at) = (vec![0.25f32; n], vec![u32::MAX; n]);
            let (mut best2, mut at2) = (best.clone(), at.clone());
            for (i, keys) in [&a, &b, &row].into_iter().enumerate() {
                unsafe { col_max(keys, &mut best, &mut at, i as u32) };
                for j in 0..n {
                    if keys[j] > best2[j] {
                        best2[j] = keys[j];
                        at2[j] = i as u32;
                    }
                }
            }
            assert!(best.iter().zip(&best2).all(|(x, y)| same(*x, *y)));
            assert_eq!(at, at2);
            // max and first position
            for x in [&a, &b, &row] {
                let mx = max_lanes(x);
                let want = if mx > 0.0 {
                    x.iter().position(|&v| v == mx).map(|j| (j, mx))
                } else {
                    None
                };
                assert_eq!(unsafe { max_first_positive(x) }, want, "row {ri}");
            }
        }
    }
}
