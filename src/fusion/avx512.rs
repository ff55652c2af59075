//! AVX-512 forms of [`super::avx2`]'s row kernels for the one-pass Noisy-AND
//! (`super::fused`): 16 lanes, the same operations per lane in the same order, and sums kept
//! in the scalar code's 8 accumulators (each 16-lane step adds its low half, then its high
//! half, to one 8-lane accumulator), so every output is bit for bit the scalar one (tested
//! against it). Maxima are folded over 16 lanes: the same value, except that a row whose
//! maximum is zero may report it as +0 or -0, which changes no output (it is only
//! subtracted, and `max_first_positive` needs it > 0).
//!
//! Callers check `crate::simd::features().float_isa() == Isa::Avx512` first.

// The scalar remainders index several slices with one position, as the scalar code does.
#![allow(clippy::needless_range_loop)]

use std::arch::x86_64::*;

use super::calibrate::fast_exp;

/// `calibrate::fast_exp` on 16 lanes (`avx2::fast_exp8`'s operations).
///
/// # Safety
/// The CPU must support AVX-512F.
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn fast_exp16(x: __m512) -> __m512 {
    let lo = _mm512_set1_ps(-87.336_54);
    let hi = _mm512_set1_ps(88.0);
    let magic = _mm512_set1_ps(12_582_912.0);
    let below = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(x, lo);
    let xc = _mm512_mask_blend_ps(below, x, lo);
    let xc = _mm512_mask_blend_ps(_mm512_cmp_ps_mask::<_CMP_GT_OQ>(xc, hi), xc, hi);
    let t = _mm512_add_ps(
        _mm512_mul_ps(xc, _mm512_set1_ps(std::f32::consts::LOG2_E)),
        magic,
    );
    let n = _mm512_sub_ps(t, magic);
    let r = _mm512_add_ps(
        _mm512_sub_ps(xc, _mm512_mul_ps(n, _mm512_set1_ps(0.693_359_4))),
        _mm512_mul_ps(n, _mm512_set1_ps(2.121_944_4e-4)),
    );
    let mut p = _mm512_add_ps(
        _mm512_mul_ps(_mm512_set1_ps(1.987_569_1e-4), r),
        _mm512_set1_ps(1.398_199_9e-3),
    );
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(8.333_452e-3));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(4.166_579_6e-2));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(1.666_666_5e-1));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), _mm512_set1_ps(0.5));
    let y = _mm512_add_ps(
        _mm512_add_ps(_mm512_mul_ps(p, _mm512_mul_ps(r, r)), r),
        _mm512_set1_ps(1.0),
    );
    let ni = _mm512_sub_epi32(
        _mm512_castps_si512(t),
        _mm512_set1_epi32(12_582_912.0f32.to_bits() as i32),
    );
    let scale = _mm512_castsi512_ps(_mm512_slli_epi32::<23>(_mm512_add_epi32(
        ni,
        _mm512_set1_epi32(127),
    )));
    // 0 where below the range, as `avx2::fast_exp8`'s andnot
    _mm512_maskz_mov_ps(!below, _mm512_mul_ps(y, scale))
}

fn lanes16(v: __m512) -> [f32; 16] {
    // SAFETY: __m512 and [f32; 16] have the same size; any bits are a valid f32.
    unsafe { std::mem::transmute::<__m512, [f32; 16]>(v) }
}

fn lanes8(v: __m256) -> [f32; 8] {
    // SAFETY: as above.
    unsafe { std::mem::transmute::<__m256, [f32; 8]>(v) }
}

/// The 16 accumulators, then the remainder, first to last (`max_lanes`' comparison).
fn max_fold(acc: __m512, rem: &[f32]) -> f32 {
    let mut m = f32::NEG_INFINITY;
    for &v in lanes16(acc).iter().chain(rem) {
        m = if v > m { v } else { m };
    }
    m
}

/// `out = src + bias`, then their maximum (`avx2::add_max`).
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn add_max(out: &mut [f32], src: &[f32], bias: &[f32]) -> f32 {
    let n = out.len().min(src.len()).min(bias.len());
    let (out, src, bias) = (&mut out[..n], &src[..n], &bias[..n]);
    let full = n - n % 16;
    let mut acc = _mm512_set1_ps(f32::NEG_INFINITY);
    for k in (0..full).step_by(16) {
        // SAFETY: k + 16 <= full <= n for all three slices (unaligned loads and store).
        let v = _mm512_add_ps(
            _mm512_loadu_ps(src.as_ptr().add(k)),
            _mm512_loadu_ps(bias.as_ptr().add(k)),
        );
        _mm512_storeu_ps(out.as_mut_ptr().add(k), v);
        // NaN in v keeps acc, as `v > m` fails for NaN
        acc = _mm512_max_ps(v, acc);
    }
    for k in full..n {
        out[k] = src[k] + bias[k];
    }
    max_fold(acc, &out[full..])
}

/// `x = fast_exp((x - mx) * it)` in place, then `sum_lanes(x)` (`avx2::exp_sum`).
///
/// # Safety
/// The CPU must support AVX-512F, AVX-512DQ and AVX2.
#[target_feature(enable = "avx512f,avx512dq,avx2")]
pub(crate) unsafe fn exp_sum(x: &mut [f32], mx: f32, it: f32) -> f32 {
    let n = x.len();
    let full16 = n - n % 16;
    let (vmx, vit) = (_mm512_set1_ps(mx), _mm512_set1_ps(it));
    // the scalar code's 8 accumulators: element k goes to lane k % 8, in order
    let mut acc = _mm256_setzero_ps();
    for k in (0..full16).step_by(16) {
        // SAFETY: k + 16 <= n.
        let p = x.as_mut_ptr().add(k);
        let e = fast_exp16(_mm512_mul_ps(_mm512_sub_ps(_mm512_loadu_ps(p), vmx), vit));
        _mm512_storeu_ps(p, e);
        acc = _mm256_add_ps(acc, _mm512_castps512_ps256(e));
        acc = _mm256_add_ps(acc, _mm512_extractf32x8_ps::<1>(e));
    }
    let mut k = full16;
    if n - k >= 8 {
        // SAFETY: k + 8 <= n; AVX2 is enabled here.
        let p = x.as_mut_ptr().add(k);
        let e = super::avx2::fast_exp8(_mm256_mul_ps(
            _mm256_sub_ps(_mm256_loadu_ps(p), _mm256_set1_ps(mx)),
            _mm256_set1_ps(it),
        ));
        _mm256_storeu_ps(p, e);
        acc = _mm256_add_ps(acc, e);
        k += 8;
    }
    for v in &mut x[k..] {
        *v = fast_exp((*v - mx) * it);
    }
    lanes8(acc).iter().sum::<f32>() + x[k..].iter().sum::<f32>()
}

/// `if p > 1 { 1 } else { p }` per lane.
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn cap(p: __m512) -> __m512 {
    let one = _mm512_set1_ps(1.0);
    _mm512_mask_blend_ps(_mm512_cmp_ps_mask::<_CMP_GT_OQ>(p, one), p, one)
}

/// The Noisy-AND rank keys of one row, `keys_j = odds_product(a_j * ia, b_j * ib)`
/// (`avx2::rank_keys`).
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn rank_keys(keys: &mut [f32], a: &[f32], b: &[f32], ia: f32, ib: f32) {
    let n = keys.len().min(a.len()).min(b.len());
    let full = n - n % 16;
    let (via, vib) = (_mm512_set1_ps(ia), _mm512_set1_ps(ib));
    let (one, zero) = (_mm512_set1_ps(1.0), _mm512_setzero_ps());
    for k in (0..full).step_by(16) {
        // SAFETY: k + 16 <= n for all three slices.
        let x = cap(_mm512_mul_ps(_mm512_loadu_ps(a.as_ptr().add(k)), via));
        let y = cap(_mm512_mul_ps(_mm512_loadu_ps(b.as_ptr().add(k)), vib));
        let p = _mm512_mul_ps(x, y);
        let q = _mm512_div_ps(
            p,
            _mm512_mul_ps(_mm512_sub_ps(one, x), _mm512_sub_ps(one, y)),
        );
        // if p > 0 { q } else { 0 } (NaN fails p > 0)
        let v = _mm512_maskz_mov_ps(_mm512_cmp_ps_mask::<_CMP_GT_OQ>(p, zero), q);
        _mm512_storeu_ps(keys.as_mut_ptr().add(k), v);
    }
    for k in full..n {
        keys[k] = super::fuse::noisy_and_rank_key(a[k] * ia, b[k] * ib);
    }
}

/// Where `keys_j > best_j`: `best_j = keys_j` and `row_j = i` (`avx2::col_max`).
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn col_max(keys: &[f32], best: &mut [f32], row: &mut [u32], i: u32) {
    let n = keys.len().min(best.len()).min(row.len());
    let full = n - n % 16;
    let vi = _mm512_set1_epi32(i as i32);
    for k in (0..full).step_by(16) {
        // SAFETY: k + 16 <= n for all three slices.
        let v = _mm512_loadu_ps(keys.as_ptr().add(k));
        let pb = best.as_mut_ptr().add(k);
        let pr = row.as_mut_ptr().add(k) as *mut i32;
        let better = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(v, _mm512_loadu_ps(pb));
        _mm512_mask_storeu_ps(pb, better, v);
        _mm512_mask_storeu_epi32(pr, better, vi);
    }
    for k in full..n {
        let better = keys[k] > best[k];
        best[k] = if better { keys[k] } else { best[k] };
        row[k] = if better { i } else { row[k] };
    }
}

/// The maximum of `x` and, when it is > 0, the first position holding it
/// (`avx2::max_first_positive`).
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn max_first_positive(x: &[f32]) -> Option<(usize, f32)> {
    let n = x.len();
    let full = n - n % 16;
    let mut acc = _mm512_set1_ps(f32::NEG_INFINITY);
    for k in (0..full).step_by(16) {
        // SAFETY: k + 16 <= n.
        acc = _mm512_max_ps(_mm512_loadu_ps(x.as_ptr().add(k)), acc);
    }
    let mx = max_fold(acc, &x[full..]);
    // NaN is not > 0
    let positive = mx > 0.0;
    if !positive {
        return None;
    }
    let vm = _mm512_set1_ps(mx);
    for k in (0..full).step_by(16) {
        // SAFETY: k + 16 <= n.
        let bits = _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(_mm512_loadu_ps(x.as_ptr().add(k)), vm);
        if bits != 0 {
            return Some((k + bits.trailing_zeros() as usize, mx));
        }
    }
    x[full..]
        .iter()
        .position(|&v| v == mx)
        .map(|j| (full + j, mx))
}

fn lanes16i(v: __m512i) -> [i32; 16] {
    // SAFETY: __m512i and [i32; 16] have the same size; any bits are a valid i32.
    unsafe { std::mem::transmute::<__m512i, [i32; 16]>(v) }
}

/// Each row's first maximum and its row-softmax probability, `streaming::row_best` of every
/// similarity row bit for bit, for a band of unit source rows `a` (rows x d, rows a multiple
/// of 8) against the transposed unit target features `bt` (d x m), `it` = 1 / tau, without
/// storing a similarity row: pass 1 forms the dot products tile by tile
/// (`simd::x86_64_avx512::dot_tile`, the FMA chains of `cosine_similarity`) and keeps per-lane
/// maxima with their first columns; pass 2 forms them again and sums `fast_exp((s - max) *
/// it)` into the scalar code's 8 accumulators, chunks of 8 columns in order. Column blocks of
/// 256 keep a block of `bt` in L1 for every row of the band. A maximum may differ from the
/// scalar fold's only in the sign of a zero, which changes neither the position (`==`) nor
/// the sum (`v - 0` and `v + 0` agree after `fast_exp`).
///
/// # Safety
/// The CPU must support AVX-512 F and DQ, AVX2 and FMA.
#[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
pub(crate) unsafe fn row_nn_band(
    a: &[f32],
    d: usize,
    bt: &[f32],
    m: usize,
    it: f32,
    out: &mut [Option<(usize, f32)>],
) {
    use crate::simd::scalar::dot_one;
    use crate::simd::x86_64_avx512::{dot_tile, TILE_COLS, TILE_ROWS};
    const BLOCK: usize = 256;
    let rows = out.len();
    assert!(
        rows.is_multiple_of(TILE_ROWS) && a.len() == rows * d && bt.len() == d * m && d > 0,
        "row-nn band: {rows} rows of {d} values in {}, a {d} x {m} transpose in {}",
        a.len(),
        bt.len()
    );
    let m32 = m - m % TILE_COLS;
    let m8 = m - m % 8;
    let mut tile = [0.0f32; TILE_ROWS * TILE_COLS];
    let iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    // Runs `$body` with `$g` (first row), `$j` (first column) and `tile` filled, over every
    // tile, column blocks outermost, so each row sees its columns in ascending order. (A
    // macro, not a closure: a closure would not be compiled with this function's features.)
    macro_rules! tiles {
        (|$g:ident, $j:ident| $body:block) => {{
            let mut j0 = 0;
            while j0 < m32 {
                let j1 = (j0 + BLOCK).min(m32);
                for $g in (0..rows).step_by(TILE_ROWS) {
                    let ag = &a[$g * d..($g + TILE_ROWS) * d];
                    for $j in (j0..j1).step_by(TILE_COLS) {
                        // SAFETY: ag holds 8 d values, j + 32 <= m32 <= m, bt holds d m
                        // values; the CPU has AVX-512F and FMA (this function's contract).
                        unsafe { dot_tile(ag, d, bt, m, $j, &mut tile) };
                        $body
                    }
                }
                j0 = j1;
            }
        }};
    }
    // pass 1: per-lane maxima (lane = column mod 16) and their first columns
    let mut vmax = vec![_mm512_set1_ps(f32::NEG_INFINITY); rows];
    let mut vidx = vec![_mm512_setzero_si512(); rows];
    tiles!(|g, j| {
        for i in 0..TILE_ROWS {
            for h in 0..2 {
                // SAFETY: the tile holds 8 x 32 values.
                let v = unsafe { _mm512_loadu_ps(tile.as_ptr().add(i * TILE_COLS + 16 * h)) };
                // NaN never replaces, as in `max_lanes`
                let gt = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(v, vmax[g + i]);
                vmax[g + i] = _mm512_mask_blend_ps(gt, vmax[g + i], v);
                let at = _mm512_add_epi32(_mm512_set1_epi32((j + 16 * h) as i32), iota);
                vidx[g + i] = _mm512_mask_blend_epi32(gt, vidx[g + i], at);
            }
        }
    });
    // the columns past the last tile, per row
    let tw = m - m32;
    let mut tail = vec![0.0f32; rows * tw];
    for r in 0..rows {
        for (q, j) in (m32..m).enumerate() {
            tail[r * tw + q] = dot_one(&a[r * d..(r + 1) * d], bt, m, j);
        }
    }
    let mut mx = vec![f32::NAN; rows];
    for r in 0..rows {
        let (lv, li) = (lanes16(vmax[r]), lanes16i(vidx[r]));
        let t = &tail[r * tw..(r + 1) * tw];
        let mut best = f32::NEG_INFINITY;
        for &v in lv.iter().chain(t) {
            best = if v > best { v } else { best };
        }
        out[r] = None;
        if !best.is_finite() {
            continue;
        }
        let first = (0..16)
            .filter(|&k| lv[k] == best)
            .map(|k| li[k] as usize)
            .min()
            .or_else(|| t.iter().position(|&v| v == best).map(|q| m32 + q));
        if let Some(j) = first {
            out[r] = Some((j, 0.0));
            mx[r] = best;
        }
    }
    // pass 2: the sums, each 16-lane step adding its low then its high half
    let vit = _mm512_set1_ps(it);
    let vmx: Vec<__m512> = mx.iter().map(|&x| _mm512_set1_ps(x)).collect();
    let mut acc = vec![_mm256_setzero_ps(); rows];
    tiles!(|g, _j| {
        for i in 0..TILE_ROWS {
            if out[g + i].is_none() {
                continue;
            }
            for h in 0..2 {
                // SAFETY: the tile holds 8 x 32 values; AVX-512 F/DQ are enabled here.
                unsafe {
                    let v = _mm512_loadu_ps(tile.as_ptr().add(i * TILE_COLS + 16 * h));
                    let e = fast_exp16(_mm512_mul_ps(_mm512_sub_ps(v, vmx[g + i]), vit));
                    acc[g + i] = _mm256_add_ps(acc[g + i], _mm512_castps512_ps256(e));
                    acc[g + i] = _mm256_add_ps(acc[g + i], _mm512_extractf32x8_ps::<1>(e));
                }
            }
        }
    });
    for r in 0..rows {
        let Some((j, _)) = out[r] else { continue };
        let (x, t) = (mx[r], &tail[r * tw..(r + 1) * tw]);
        let mut l = lanes8(acc[r]);
        let (full, rem) = t.split_at(m8 - m32);
        for c in full.chunks_exact(8) {
            for k in 0..8 {
                l[k] += fast_exp((c[k] - x) * it);
            }
        }
        let z = l.iter().sum::<f32>() + rem.iter().map(|&v| fast_exp((v - x) * it)).sum::<f32>();
        out[r] = Some((j, 1.0 / z));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::avx2::tests::{rows, same};
    use crate::fusion::calibrate::{max_lanes, sum_lanes};

    fn have() -> bool {
        crate::simd::features().float_isa() == crate::simd::Isa::Avx512
    }

    #[test]
    fn every_kernel_gives_the_scalar_bits() {
        if !have() {
            eprintln!("no AVX-512 on this CPU: the 16-lane kernels are not exercised");
            return;
        }
        for (ri, row) in rows(7).into_iter().enumerate() {
            let n = row.len();
            let bias: Vec<f32> = (0..n)
                .map(|j| if j % 5 == 3 { f32::NEG_INFINITY } else { 0.0 })
                .collect();
            let mut out = vec![0.0; n];
            let m = unsafe { add_max(&mut out, &row, &bias) };
            let want: Vec<f32> = row.iter().zip(&bias).map(|(a, b)| a + b).collect();
            assert!(out.iter().zip(&want).all(|(a, b)| same(*a, *b)), "row {ri}");
            assert!(
                same(m, max_lanes(&want)),
                "row {ri}: {m} vs {}",
                max_lanes(&want)
            );
            for (mx, it) in [(0.9f32, 10.0f32), (1.5, 1.0 / 0.12), (0.0, 100.0)] {
                let mut x = row.clone();
                let s = unsafe { exp_sum(&mut x, mx, it) };
                let e: Vec<f32> = row.iter().map(|&v| fast_exp((v - mx) * it)).collect();
                assert!(x.iter().zip(&e).all(|(a, b)| same(*a, *b)), "row {ri}");
                assert!(same(s, sum_lanes(&e)), "row {ri}: {s} vs {}", sum_lanes(&e));
            }
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
            let (mut best, mut at) = (vec![0.25f32; n], vec![u32::MAX; n]);
            let (mut best2, mut at2) = (best.clone(), at.clone());
            for (i, keys) in [&a, &b, &row, &a].into_iter().enumerate() {
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
