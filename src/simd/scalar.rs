//! Portable kernels: the reference every vectorised kernel is tested against.

use super::PairColumns;

/// `|a & b|`: bits set in both.
#[inline(always)]
pub fn and_popcount(a: &[u64], b: &[u64]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x & y).count_ones()).sum()
}

/// SC2-PCR's compatibility row: words `w0..words` of row i (columns `64 w0..n`) of the bitsets
/// `hard = C < d`, `tight = C < d/2` and `near = Ds < nms`, where `Ds = ‖s_i − s_j‖` and
/// `C = |Ds − ‖t_i − t_j‖|`, and the values `clamp(1 − C²/d², 0)` of the set `hard` bits with
/// column > i (the upper triangle; SC is symmetric), pushed as (column, value).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn compat_row(
    p: PairColumns,
    i: usize,
    d: f32,
    nms: f32,
    w0: usize,
    words: usize,
    (hard, tight, near): (&mut [u64], &mut [u64], &mut [u64]),
    vals: &mut Vec<(u32, f32)>,
) {
    let half = d / 2.0;
    let d2 = d * d;
    let mut c = [0f32; 64];
    let mut ds = [0f32; 64];
    let n = p.len();
    let ([sx, sy, sz], [tx, ty, tz]) = (p.src, p.tgt);
    let (xi, yi, zi) = (sx[i], sy[i], sz[i]);
    let (ui, vi, wi) = (tx[i], ty[i], tz[i]);
    for w in w0..words {
        let base = w * 64;
        let len = (n - base).min(64);
        // Same arithmetic as SC2-PCR's `Soa::cross`, over slices so that it vectorises.
        let r = base..base + len;
        let (sx, sy, sz) = (&sx[r.clone()], &sy[r.clone()], &sz[r.clone()]);
        let (tx, ty, tz) = (&tx[r.clone()], &ty[r.clone()], &tz[r]);
        for k in 0..len {
            let (dx, dy, dz) = (xi - sx[k], yi - sy[k], zi - sz[k]);
            let a = (dx * dx + dy * dy + dz * dz).sqrt();
            let (ex, ey, ez) = (ui - tx[k], vi - ty[k], wi - tz[k]);
            let b = (ex * ex + ey * ey + ez * ez).sqrt();
            ds[k] = a;
            c[k] = (a - b).abs();
        }
        let (mut h, mut t, mut r) = (0u64, 0u64, 0u64);
        for k in 0..len {
            h |= ((c[k] < d) as u64) << k;
            t |= ((c[k] < half) as u64) << k;
            r |= ((ds[k] < nms) as u64) << k;
        }
        hard[w] = h;
        tight[w] = t;
        near[w] = r;
        // Upper triangle only: columns > i.
        let mut m = if w == i / 64 {
            h & (u64::MAX << (i % 64)) & !(1u64 << (i % 64))
        } else {
            h
        };
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            vals.push(((base + k) as u32, (1.0 - c[k] * c[k] / d2).max(0.0)));
            m &= m - 1;
        }
    }
}

/// `out[r][j] = a_r · b_j` for the rows of `a` (rows x d, row-major) against `bt`, the
/// transpose of b (d x m, row-major: its column j is b's row j); `out` is rows x m. Each sum is
/// one fused multiply-add chain over k = 0..d from +0: the arithmetic of the blocked sgemm's
/// FMA kernels (matrixmultiply, for d up to its 256-deep k block), so the result has their
/// bits. Compiled without FMA, every `mul_add` is a C library call: the reference the FMA
/// kernels are tested against, not a fast path.
///
/// Panics when the slice lengths disagree (a caller bug, never data-dependent).
#[inline(always)]
pub fn dot_rows(a: &[f32], d: usize, bt: &[f32], m: usize, out: &mut [f32]) {
    let rows = dot_rows_shape(a, d, bt, m, out);
    for r in 0..rows {
        for j in 0..m {
            out[r * m + j] = dot_one(&a[r * d..(r + 1) * d], bt, m, j);
        }
    }
}

/// The number of rows of [`dot_rows`]'s `a`, once every length has been checked against `d`
/// and `m` (the FMA kernels' pointer arithmetic relies on it); panics on a mismatch.
#[inline(always)]
pub fn dot_rows_shape(a: &[f32], d: usize, bt: &[f32], m: usize, out: &[f32]) -> usize {
    let rows = a.len().checked_div(d).unwrap_or(0);
    assert!(
        rows * d == a.len() && bt.len() == d * m && out.len() == rows * m,
        "dot_rows: {} values of {d}-D rows against a {d} x {m} transpose into {} values",
        a.len(),
        out.len()
    );
    rows
}

/// One entry of [`dot_rows`]: row `x` (d values) against column `j` of `bt` (d x m).
#[inline(always)]
pub fn dot_one(x: &[f32], bt: &[f32], m: usize, j: usize) -> f32 {
    let mut acc = 0.0f32;
    for (k, v) in x.iter().enumerate() {
        acc = v.mul_add(bt[k * m + j], acc);
    }
    acc
}
