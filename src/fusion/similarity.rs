//! Cosine similarity of L2-normalised features (paper eq. 2-3, reference §8.1-8.2).

use super::matrix::{rows_per_task, DenseMatrix};
use crate::features::Features;
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

/// `out[r][j] = a_band[r] · b[j]` for a band of rows `a_band` (rows x d, row-major) against all
/// of `b` (m x d, row-major, read as its transpose), with one blocked sgemm; `out` is rows x m.
/// Panics when the slice lengths disagree with `d` (a caller bug, never data-dependent).
pub(crate) fn dot_band(a_band: &[f32], b: &[f32], d: usize, out: &mut [f32]) {
    if d == 0 {
        out.fill(0.0);
        return;
    }
    let rows = a_band.len() / d;
    let m = b.len() / d;
    assert!(
        a_band.len() == rows * d && b.len() == m * d && out.len() == rows * m,
        "dot_band: {} x {d} against {} x {d} into {} values",
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

/// `S[i][j] = cos(src_i, tgt_j)`: both sides L2-normalised, then one blocked sgemm per band
/// of source rows, bands run in parallel.
pub fn cosine_similarity(src: &Features, tgt: &Features) -> Result<DenseMatrix> {
    if src.dim != tgt.dim {
        return Err(Error::Invalid(format!(
            "cosine similarity: source features are {}-D, target features {}-D",
            src.dim, tgt.dim
        )));
    }
    for (what, f) in [("source", src), ("target", tgt)] {
        if f.dim > 0 && f.data.len() % f.dim != 0 {
            return Err(Error::Invalid(format!(
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
    // Bands of 64+ rows keep sgemm's packing of B amortised while giving rayon enough tasks.
    let band = rows_per_task(n, m, 1 << 18).max(64).min(n);
    out.data
        .par_chunks_mut(band * m)
        .enumerate()
        .for_each(|(t, c)| {
            let r0 = t * band;
            let rows = c.len() / m;
            dot_band(&a.data[r0 * d..(r0 + rows) * d], &b.data, d, c);
        });
    Ok(out)
}

/// Paper eq. 3: the element-wise maximum of the cosine similarities of several view pairs
/// `(source view features, target view features)`, all over the same source and target points.
pub fn max_similarity(pairs: &[(Features, Features)]) -> Result<DenseMatrix> {
    let Some((first, rest)) = pairs.split_first() else {
        return Err(Error::Invalid("max similarity: no view pairs".into()));
    };
    let mut acc = cosine_similarity(&first.0, &first.1)?;
    for (k, (s, t)) in rest.iter().enumerate() {
        let sk = cosine_similarity(s, t)?;
        if sk.shape() != acc.shape() {
            return Err(Error::Invalid(format!(
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
