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

/// Rows of the FMA dot-product tile ([`dot_tile`]).
pub const TILE_ROWS: usize = 8;
/// Columns of the FMA dot-product tile ([`dot_tile`]).
pub const TILE_COLS: usize = 32;

/// One 8 x 32 tile of [`super::dot_rows`]: rows `a[0..8]` (row stride `d`) against columns
/// `j..j + 32` of `bt` (d x m, row stride `m`), each entry the exact FMA chain over k in order
/// ([`super::scalar::dot_one`]'s bits), into `out` (8 x 32, row stride 32).
///
/// # Safety
/// The CPU must support AVX-512F and FMA; `a` holds `8 d` values, `j + 32 <= m` and `bt`
/// holds `d m` values.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub unsafe fn dot_tile(
    a: &[f32],
    d: usize,
    bt: &[f32],
    m: usize,
    j: usize,
    out: &mut [f32; TILE_ROWS * TILE_COLS],
) {
    use std::arch::x86_64::*;
    debug_assert!(a.len() >= TILE_ROWS * d && j + TILE_COLS <= m && bt.len() >= d * m);
    let mut c = [_mm512_setzero_ps(); 2 * TILE_ROWS];
    let ap = a.as_ptr();
    // SAFETY: the caller guarantees the lengths: rows 0..8 of `a` hold k < d, and columns
    // j..j+32 < m of every row k < d of `bt` are in bounds.
    unsafe {
        let mut bp = bt.as_ptr().add(j);
        for k in 0..d {
            let b0 = _mm512_loadu_ps(bp);
            let b1 = _mm512_loadu_ps(bp.add(16));
            for i in 0..TILE_ROWS {
                let x = _mm512_set1_ps(*ap.add(i * d + k));
                c[2 * i] = _mm512_fmadd_ps(x, b0, c[2 * i]);
                c[2 * i + 1] = _mm512_fmadd_ps(x, b1, c[2 * i + 1]);
            }
            bp = bp.add(m);
        }
        let op = out.as_mut_ptr();
        for i in 0..TILE_ROWS {
            _mm512_storeu_ps(op.add(i * TILE_COLS), c[2 * i]);
            _mm512_storeu_ps(op.add(i * TILE_COLS + 16), c[2 * i + 1]);
        }
    }
}

/// [`super::scalar::dot_rows`] with [`dot_tile`] (8 rows x 32 columns, column blocks of 256
/// so that a block of `bt` is reused from L1 by every row); the rows past the last multiple
/// of 8 go through the AVX2 kernel. The same bits as every other `dot_rows`.
///
/// # Safety
/// The CPU must support AVX-512F, AVX2 and FMA.
#[target_feature(enable = "avx512f,avx2,fma")]
pub unsafe fn dot_rows(a: &[f32], d: usize, bt: &[f32], m: usize, out: &mut [f32]) {
    const BLOCK: usize = 256;
    let rows = super::scalar::dot_rows_shape(a, d, bt, m, out);
    let full = rows - rows % TILE_ROWS;
    let mut tile = [0.0f32; TILE_ROWS * TILE_COLS];
    let mut j0 = 0;
    while j0 < m {
        let j1 = (j0 + BLOCK).min(m);
        let jv = j0 + (j1 - j0) / TILE_COLS * TILE_COLS;
        for r in (0..full).step_by(TILE_ROWS) {
            let ar = &a[r * d..(r + TILE_ROWS) * d];
            for j in (j0..jv).step_by(TILE_COLS) {
                // SAFETY: the features are checked above; ar holds 8 d values, j + 32 <= m.
                unsafe { dot_tile(ar, d, bt, m, j, &mut tile) };
                for i in 0..TILE_ROWS {
                    let o = (r + i) * m + j;
                    out[o..o + TILE_COLS]
                        .copy_from_slice(&tile[i * TILE_COLS..(i + 1) * TILE_COLS]);
                }
            }
            for i in r..r + TILE_ROWS {
                for j in jv..j1 {
                    out[i * m + j] = super::scalar::dot_one(&a[i * d..(i + 1) * d], bt, m, j);
                }
            }
        }
        j0 = j1;
    }
    if full < rows {
        // SAFETY: AVX2 and FMA are enabled here.
        unsafe { super::x86_64_avx2::dot_rows(&a[full * d..], d, bt, m, &mut out[full * m..]) };
    }
}
