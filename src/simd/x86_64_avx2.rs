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

/// [`super::scalar::dot_rows`] with AVX2 + FMA: tiles of 4 rows x 16 columns, their sums in
/// eight registers, each pair of loads from `bt` serving four rows, over blocks of 256 columns
/// (the `d x 256` slice of `bt` stays in cache while every row passes over it); the edges one
/// entry at a time. Every sum is the same FMA chain in the same order, so the bits are the
/// reference's.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub unsafe fn dot_rows(a: &[f32], d: usize, bt: &[f32], m: usize, out: &mut [f32]) {
    use std::arch::x86_64::*;
    const ROWS: usize = 4;
    const LANES: usize = 16;
    const BLOCK: usize = 256;
    let rows = super::scalar::dot_rows_shape(a, d, bt, m, out);
    let scalar = super::scalar::dot_one;
    let mut j0 = 0;
    while j0 < m {
        let j1 = (j0 + BLOCK).min(m);
        let jv = j0 + (j1 - j0) / LANES * LANES;
        let mut r = 0;
        while r + ROWS <= rows {
            let mut j = j0;
            while j < jv {
                // SAFETY: rows r..r+4 of `a` hold 4 d values from r d, columns j..j+16 < m of
                // every row k < d of `bt` are in bounds (the lengths were checked above), and
                // the stores go to rows r..r+4, columns j..j+16 of `out`.
                unsafe {
                    let ap = a.as_ptr().add(r * d);
                    let mut bp = bt.as_ptr().add(j);
                    let mut c = [_mm256_setzero_ps(); 2 * ROWS];
                    for k in 0..d {
                        let b0 = _mm256_loadu_ps(bp);
                        let b1 = _mm256_loadu_ps(bp.add(8));
                        for i in 0..ROWS {
                            let x = _mm256_set1_ps(*ap.add(i * d + k));
                            c[2 * i] = _mm256_fmadd_ps(x, b0, c[2 * i]);
                            c[2 * i + 1] = _mm256_fmadd_ps(x, b1, c[2 * i + 1]);
                        }
                        bp = bp.add(m);
                    }
                    for i in 0..ROWS {
                        let op = out.as_mut_ptr().add((r + i) * m + j);
                        _mm256_storeu_ps(op, c[2 * i]);
                        _mm256_storeu_ps(op.add(8), c[2 * i + 1]);
                    }
                }
                j += LANES;
            }
            for i in r..r + ROWS {
                for j in jv..j1 {
                    out[i * m + j] = scalar(&a[i * d..(i + 1) * d], bt, m, j);
                }
            }
            r += ROWS;
        }
        for i in r..rows {
            for j in j0..j1 {
                out[i * m + j] = scalar(&a[i * d..(i + 1) * d], bt, m, j);
            }
        }
        j0 = j1;
    }
}
