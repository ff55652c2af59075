//! Cosine similarity of L2-normalised features (paper eq. 2-3, reference §8.1-8.2).

use crate::features::Features;
use crate::matrix::{rows_per_task, DenseMatrix};
use crate::simd::Isa;
use crate::{Error, Result};
use rayon::prelude::*;

/// Normalisation floor, as `torch.nn.functional.normalize(eps=1e-6)`: x / max(|x|, eps).
const NORM_EPS: f32 = 1e-6;

/// Rows scaled to unit L2 norm the way the reference does it (zero rows stay zero).
pub fn normalize_rows(f: &Features) -> Features {
    let mut data = f.data.clone();
    if f.dim > 0 {
        data.par_chunks_mut(f.dim).for_each(|row| {
            let n = row.iter().map(|v| v * v).sum::<f32>().sqrt().max(NORM_EPS);
            let inv = 1.0 / n;
            row.iter_mut().for_each(|v| *v *= inv);
        });
    }
    Features { dim: f.dim, data }
}

/// The depth of the blocked sgemm's k block (matrixmultiply's `S_KC`): up to it, a dot product
/// is one FMA chain there, which the FMA kernel reproduces bit for bit.
const SGEMM_KC: usize = 256;

/// The right-hand side of [`dot_band`]: target features (m x d, row-major), laid out once per
/// matrix for the kernel this CPU runs. With AVX2 + FMA and d ≤ 256 they are transposed (d x m)
/// for [`crate::simd::dot_rows`], which reads them in place; otherwise each band goes through
/// the blocked sgemm, which packs them again for every band (as much work as the products when
/// d is a few dozen). Both give the same bits where both run.
pub(crate) struct DotRhs<'a> {
    b: &'a [f32],
    d: usize,
    m: usize,
    isa: Isa,
    /// `b` transposed, for the FMA kernel (empty with sgemm).
    bt: Vec<f32>,
}

impl<'a> DotRhs<'a> {
    pub fn new(f: &'a Features) -> Self {
        let (d, m) = (f.dim, f.len());
        let isa = match crate::simd::features().fma_isa() {
            Isa::Scalar => Isa::Scalar,
            _ if d == 0 || d > SGEMM_KC => Isa::Scalar,
            isa => isa,
        };
        let mut bt = Vec::new();
        if isa != Isa::Scalar {
            bt = vec![0.0f32; d * m];
            bt.par_chunks_mut(m.max(1))
                .enumerate()
                .for_each(|(k, row)| {
                    for (j, v) in row.iter_mut().enumerate() {
                        *v = f.data[j * d + k];
                    }
                });
        }
        DotRhs {
            b: &f.data[..d * m],
            d,
            m,
            isa,
            bt,
        }
    }

    /// Target rows.
    pub fn len(&self) -> usize {
        self.m
    }

    pub fn dim(&self) -> usize {
        self.d
    }

    /// The target features transposed (d x m) for the FMA kernels; None where `dot_band`
    /// takes the sgemm.
    pub fn transposed(&self) -> Option<&[f32]> {
        (self.isa != Isa::Scalar).then_some(&self.bt[..])
    }
}

/// `out[r][j] = a_band[r] · b[j]` for a band of rows `a_band` (rows x d, row-major) against all
/// of `b`'s rows; `out` is rows x m.
/// Panics when the slice lengths disagree with `d` (a caller bug, never data-dependent).
pub(crate) fn dot_band(a_band: &[f32], b: &DotRhs<'_>, out: &mut [f32]) {
    let (d, m) = (b.d, b.m);
    if d == 0 {
        out.fill(0.0);
        return;
    }
    // Each kernel checks the lengths itself (its pointer arithmetic relies on them).
    if b.isa != Isa::Scalar {
        crate::simd::dot_rows(b.isa, a_band, d, &b.bt, m, out);
        return;
    }
    sgemm_band(a_band, b.b, d, out);
}

/// [`dot_band`] by one blocked sgemm: `b` (m x d, row-major) read as its transpose.
fn sgemm_band(a_band: &[f32], b: &[f32], d: usize, out: &mut [f32]) {
    let rows = a_band.len() / d;
    let m = b.len() / d;
    assert!(
        a_band.len() == rows * d && b.len() == m * d && out.len() == rows * m,
        "sgemm band: {} x {d} against {} x {d} into {} values",
        rows,
        m,
        out.len()
    );
    // SAFETY: a_band is rows x d (row stride d), b is m x d read as its transpose d x m (row
    // stride 1, column stride d), out is rows x m (row stride m); the lengths were checked
    // above and the slices do not alias (out is the only &mut).
    unsafe {
        matrixmultiply::sgemm(
            rows,
            d,
            m,
            1.0,
            a_band.as_ptr(),
            d as isize,
            1,
            b.as_ptr(),
            1,
            d as isize,
            0.0,
            out.as_mut_ptr(),
            m as isize,
            1,
        );
    }
}

/// `S[i][j] = cos(src_i, tgt_j)`: both sides L2-normalised, then [`dot_band`] per band of
/// source rows, bands run in parallel.
pub fn cosine_similarity(src: &Features, tgt: &Features) -> Result<DenseMatrix> {
    if src.dim != tgt.dim {
        return Err(Error::Shape(format!(
            "cosine similarity: source features are {}-D, target features {}-D",
            src.dim, tgt.dim
        )));
    }
    for (what, f) in [("source", src), ("target", tgt)] {
        if f.dim > 0 && f.data.len() % f.dim != 0 {
            return Err(Error::Shape(format!(
                "cosine similarity: {what} features hold {} values, not a multiple of {}",
                f.data.len(),
                f.dim
            )));
        }
    }
    let (n, m, d) = (src.len(), tgt.len(), src.dim);
    let mut out = DenseMatrix::zeros(n, m)?;
    if n == 0 || m == 0 || d == 0 {
        return Ok(out);
    }
    let a = normalize_rows(src);
    let b = normalize_rows(tgt);
    let rhs = DotRhs::new(&b);
    // Bands of 64+ rows keep sgemm's packing of B amortised while giving rayon enough tasks.
    let band = rows_per_task(n, m, 1 << 18).max(64).min(n);
    out.data
        .par_chunks_mut(band * m)
        .enumerate()
        .for_each(|(t, c)| {
            let r0 = t * band;
            let rows = c.len() / m;
            dot_band(&a.data[r0 * d..(r0 + rows) * d], &rhs, c);
        });
    Ok(out)
}

/// Paper eq. 3: the element-wise maximum of the cosine similarities of several view pairs
/// `(source view features, target view features)`, all over the same source and target points.
pub fn max_similarity(pairs: &[(Features, Features)]) -> Result<DenseMatrix> {
    let Some((first, rest)) = pairs.split_first() else {
        return Err(Error::Missing("max similarity: no view pairs".into()));
    };
    let mut acc = cosine_similarity(&first.0, &first.1)?;
    for (k, (s, t)) in rest.iter().enumerate() {
        let sk = cosine_similarity(s, t)?;
        if sk.shape() != acc.shape() {
            return Err(Error::Shape(format!(
                "max similarity: view pair {} is {} x {}, view pair 0 is {} x {}",
                k + 1,
                sk.rows,
                sk.cols,
                acc.rows,
                acc.cols
            )));
        }
        acc.data
            .par_iter_mut()
            .zip(sk.data.par_iter())
            .with_min_len(1 << 14)
            .for_each(|(a, b)| *a = a.max(*b));
    }
    Ok(acc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Lcg;

    fn random_features(n: usize, d: usize, seed: u64) -> Features {
        let mut s = Lcg(seed);
        Features::new(d, (0..n * d).map(|_| s.signed_f32()).collect())
    }

    #[test]
    fn cosine_matches_brute_force() {
        let (n, m, d) = (150, 97, 33);
        let mut src = random_features(n, d, 1);
        let tgt = random_features(m, d, 2);
        src.data[5 * d..6 * d].iter_mut().for_each(|v| *v = 0.0); // zero row stays zero
        let s = cosine_similarity(&src, &tgt).unwrap();
        assert_eq!(s.shape(), (n, m));
        for i in 0..n {
            for j in 0..m {
                let (a, b) = (src.row(i), tgt.row(j));
                let dot: f64 = a
                    .iter()
                    .zip(b)
                    .map(|(x, y)| (*x as f64) * (*y as f64))
                    .sum();
                let na: f64 = a.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
                let nb: f64 = b.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
                let want = if na == 0.0 { 0.0 } else { dot / (na * nb) };
                assert!((s.get(i, j) as f64 - want).abs() < 1e-5, "({i},{j})");
            }
        }
        assert!(cosine_similarity(&src, &random_features(3, 8, 3)).is_err());
        let empty = cosine_similarity(&Features::new(d, vec![]), &tgt).unwrap();
        assert_eq!(empty.shape(), (0, m));
    }

    /// The FMA kernel against the sgemm it replaces, bit for bit, and against an FMA chain
    /// written out, over shapes that leave every tile edge (rows mod 4, columns mod 16 and
    /// mod 256) and every depth up to sgemm's k block (a row of -0 included).
    #[test]
    fn fma_kernel_has_the_sgemm_bits() {
        if crate::simd::features().fma_isa() == Isa::Scalar {
            eprintln!("skipping: no AVX2 + FMA on this CPU");
            return;
        }
        let seed = 0x05ee_dd07;
        let mut dims = Lcg(seed);
        for case in 0..40u64 {
            let d = [1, 2, 3, 7, 8, 24, 32, 33, 64, 65, 128, 255, 256][case as usize % 13];
            let rows = 1 + (dims.next_u64() % 70) as usize;
            let m = 1 + (dims.next_u64() % 600) as usize;
            let mut a = random_features(rows, d, seed ^ (2 * case + 1));
            a.data[..d].iter_mut().for_each(|v| *v = -0.0);
            let b = random_features(m, d, seed ^ (2 * case + 2));
            let rhs = DotRhs::new(&b);
            assert_ne!(rhs.isa, Isa::Scalar, "d = {d} takes the FMA kernel");
            let (mut fast, mut gemm) = (vec![1.0f32; rows * m], vec![2.0f32; rows * m]);
            dot_band(&a.data, &rhs, &mut fast);
            sgemm_band(&a.data, &b.data, d, &mut gemm);
            let chain = |i: usize, j: usize| {
                let mut acc = 0.0f32;
                for k in 0..d {
                    acc = a.data[i * d + k].mul_add(b.data[j * d + k], acc);
                }
                acc
            };
            for i in 0..rows {
                for j in 0..m {
                    let (x, y) = (fast[i * m + j], gemm[i * m + j]);
                    assert_eq!(
                        x.to_bits(),
                        y.to_bits(),
                        "seed {seed:#x} case {case}: {rows} x {m} x {d} at ({i}, {j}): {x} vs {y}"
                    );
                    assert_eq!(x.to_bits(), chain(i, j).to_bits(), "case {case} ({i}, {j})");
                }
            }
        }
        // deeper than sgemm's k block: sgemm itself
        let b = random_features(5, SGEMM_KC + 1, 9);
        assert_eq!(DotRhs::new(&b).isa, Isa::Scalar);
    }

    #[test]
    fn max_over_view_pairs() {
        let pairs: Vec<_> = (0..3)
            .map(|k| {
                (
                    random_features(20, 8, 10 + k),
                    random_features(30, 8, 20 + k),
                )
            })
            .collect();
        let s = max_similarity(&pairs).unwrap();
        let each: Vec<_> = pairs
            .iter()
            .map(|(a, b)| cosine_similarity(a, b).unwrap())
            .collect();
        for i in 0..20 {
            for j in 0..30 {
                let want = each.iter().map(|e| e.get(i, j)).fold(f32::MIN, f32::max);
                assert_eq!(s.get(i, j), want);
            }
        }
        assert!(max_similarity(&[]).is_err());
        let bad = vec![
            pairs[0].clone(),
            (random_features(21, 8, 1), random_features(30, 8, 2)),
        ];
        assert!(max_similarity(&bad).is_err());
    }
}
