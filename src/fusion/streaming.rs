//! Geometry-only matching without an N x M matrix: similarity, row-softmax posterior and each
//! source point's best target, computed band by band. It gives exactly what the dense path
//! (cosine similarity -> `RowSoftmax` -> `GeometryOnly` -> `RowNn`) gives, because the row
//! softmax is monotone within a row: the argmax is the similarity's argmax and its posterior
//! is 1 / sum_j exp((s_ij - s_max) / tau). Memory is one band of rows, not N x M.

use super::calibrate::fast_exp;
use super::similarity::normalize_rows;
use super::Correspondence;
use crate::features::Features;
use crate::{Error, Result};
use rayon::prelude::*;

const BAND: usize = 128;

/// Every source row's best target with its row-softmax posterior (temperature `tau`), sorted by
/// (score descending, source, target) like `select`.
pub fn row_nn_posterior(src: &Features, tgt: &Features, tau: f32) -> Result<Vec<Correspondence>> {
    if src.dim != tgt.dim {
        return Err(Error::Shape(format!(
            "row-nn: source features are {}-D, target features {}-D",
            src.dim, tgt.dim
        )));
    }
    check_tau(tau)?;
    let (n, m, d) = (src.len(), tgt.len(), src.dim);
    if n == 0 || m == 0 || d == 0 {
        return Ok(Vec::new());
    }
    let a = normalize_rows(src);
    let b = normalize_rows(tgt);
    let rhs = super::similarity::DotRhs::new(&b);
    let it = 1.0 / tau;
    let fused = fused_row_nn(&rhs);
    let mut out: Vec<Correspondence> = a
        .data
        .par_chunks(BAND * d)
        .enumerate()
        .map_init(Vec::new, |s, (t, a_band)| {
            let rows = a_band.len() / d;
            // a cancelled run skips the remaining bands (checked after the loop)
            if crate::cancel::requested() {
                return Vec::new();
            }
            let mut best = vec![None; rows];
            // The fused kernel takes the rows in multiples of 8 and holds no similarity row;
            // the rest (and every row without it) goes through one band buffer per task.
            let done = match fused {
                #[cfg(target_arch = "x86_64")]
                Some(bt) => {
                    let r8 = rows - rows % 8;
                    // SAFETY: `fused_row_nn` gave `bt` only on a CPU with AVX-512 F/DQ, AVX2
                    // and FMA; the lengths are the band's.
                    unsafe {
                        super::avx512::row_nn_band(&a_band[..r8 * d], d, bt, m, it, &mut best[..r8])
                    };
                    r8
                }
                _ => 0,
            };
            if done < rows {
                // grows once per task; the kernel writes every value it reads
                s.resize((rows - done) * m, 0.0);
                let s = &mut s[..(rows - done) * m];
                super::similarity::dot_band(&a_band[done * d..], &rhs, s);
                for (r, b) in best[done..].iter_mut().enumerate() {
                    *b = row_best(&s[r * m..(r + 1) * m], it);
                }
            }
            let base = t * BAND;
            best.into_iter()
                .enumerate()
                .filter_map(|(r, b)| {
                    let (j, score) = b?;
                    Some(Correspondence {
                        src: (base + r) as u32,
                        tgt: j as u32,
                        score,
                    })
                })
                .collect::<Vec<_>>()
        })
        .flatten_iter()
        .collect();
    crate::cancel::check()?;
    out.sort_unstable_by(super::select::order);
    Ok(out)
}

/// The transposed target features for `avx512::row_nn_band` when this CPU runs it (AVX-512
/// F/DQ with the FMA dot kernel), else None.
fn fused_row_nn<'r>(rhs: &'r super::similarity::DotRhs<'_>) -> Option<&'r [f32]> {
    let f = crate::simd::features();
    let wide = f.float_isa() == crate::simd::Isa::Avx512 && f.fma_isa() == crate::simd::Isa::Avx512;
    rhs.transposed()
        .filter(|_| wide && cfg!(target_arch = "x86_64"))
}

/// The row-NN paths' temperature check (one message for all three).
fn check_tau(tau: f32) -> Result<()> {
    if tau > 0.0 && tau.is_finite() {
        Ok(())
    } else {
        Err(Error::Param(format!(
            "row-nn: temperature must be > 0, got {tau}"
        )))
    }
}

/// A row's first argmax and its row-softmax probability 1 / sum_j exp((s_j - max) / tau), with
/// `it` = 1/tau. Max and sum run in 8 independent lanes so they vectorise (the sequential
/// fold/sum were most of the time); both streaming paths share it, so they agree bit for bit.
/// An AVX2 build of it measured no faster: at 5k x 5k it reads 100 MB per pass.
#[inline]
fn row_best(row: &[f32], it: f32) -> Option<(usize, f32)> {
    let (j, mx) = row_max(row)?;
    Some((j, row_p(row, mx, it)))
}

/// A row's maximum and its first position; None when the maximum is not finite.
#[inline]
fn row_max(row: &[f32]) -> Option<(usize, f32)> {
    let mx = super::calibrate::max_lanes(row);
    if !mx.is_finite() {
        return None;
    }
    Some((row.iter().position(|&v| v == mx)?, mx))
}

/// 1 / sum_j exp((s_j - mx) * it): the row-softmax probability of the row's maximum `mx`.
#[inline]
fn row_p(row: &[f32], mx: f32, it: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::features().avx2 {
        // SAFETY: the CPU has AVX2 (checked at run time).
        return unsafe { super::avx2::inv_exp_sum(row, mx, it) };
    }
    row_p_scalar(row, mx, it)
}

#[inline]
#[allow(clippy::needless_range_loop)]
fn row_p_scalar(row: &[f32], mx: f32, it: f32) -> f32 {
    let mut acc = [0.0f32; 8];
    let chunks = row.chunks_exact(8);
    let rem = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            acc[k] += fast_exp((c[k] - mx) * it);
        }
    }
    let z = acc.iter().sum::<f32>() + rem.iter().map(|&v| fast_exp((v - mx) * it)).sum::<f32>();
    1.0 / z
}

/// Each row's maximum and its first position (None: no finite maximum): what
/// [`row_nn_from_maxima`] needs besides the matrix, for any temperature.
pub fn row_maxima(sim: &crate::matrix::DenseMatrix) -> Vec<Option<(u32, f32)>> {
    if sim.cols == 0 {
        return vec![None; sim.rows];
    }
    sim.data
        .par_chunks(sim.cols)
        .map(|row| row_max(row).map(|(j, mx)| (j as u32, mx)))
        .collect()
}

/// [`row_nn_from_similarity`] with each row's maximum found before ([`row_maxima`] of `sim`):
/// one pass over the matrix instead of three; the same correspondences, scores and order.
pub fn row_nn_from_maxima(
    sim: &crate::matrix::DenseMatrix,
    maxima: &[Option<(u32, f32)>],
    tau: f32,
) -> Result<Vec<Correspondence>> {
    check_tau(tau)?;
    let m = sim.cols;
    if sim.rows == 0 || m == 0 {
        return Ok(Vec::new());
    }
    if maxima.len() != sim.rows {
        return Err(Error::Shape(format!(
            "row-nn: {} row maxima for a matrix of {} rows",
            maxima.len(),
            sim.rows
        )));
    }
    let it = 1.0 / tau;
    let mut out: Vec<Correspondence> = sim
        .data
        .par_chunks(m)
        .zip(maxima.par_iter())
        .enumerate()
        .filter_map(|(i, (row, best))| {
            let (j, mx) = (*best)?;
            Some(Correspondence {
                src: i as u32,
                tgt: j,
                score: row_p(row, mx, it),
            })
        })
        .collect();
    out.sort_unstable_by(super::select::order);
    Ok(out)
}

/// [`row_nn_posterior`] from a similarity matrix computed before (the inspector keeps it): each
/// row's best target with its row-softmax probability, in one pass, without another matrix.
pub fn row_nn_from_similarity(
    sim: &crate::matrix::DenseMatrix,
    tau: f32,
) -> Result<Vec<Correspondence>> {
    check_tau(tau)?;
    let m = sim.cols;
    if sim.rows == 0 || m == 0 {
        return Ok(Vec::new());
    }
    let it = 1.0 / tau;
    Ok(sim
        .data
        .par_chunks(m)
        .enumerate()
        .filter_map(|(i, row)| {
            let (j, score) = row_best(row, it)?;
            Some(Correspondence {
                src: i as u32,
                tgt: j as u32,
                score,
            })
        })
        .collect::<Vec<_>>())
    .map(|mut out| {
        // the same order as row_nn_posterior
        out.sort_unstable_by(super::select::order);
        out
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::{match_then_fuse, Calibration, FusionMode, FusionParams, Selection};

    fn feats(n: usize, d: usize, seed: u64) -> Features {
        let mut s = crate::testing::Lcg(seed);
        let data = (0..n * d).map(|_| s.unit_f32()).collect();
        Features::new(d, data)
    }

    /// The AVX2 sum is the scalar one bit for bit (lanes, remainders, underflow, -inf, NaN),
    /// and the row-NN from kept maxima is the one from the matrix.
    #[test]
    fn kept_maxima_and_avx2_sum_give_the_same_bits() {
        let f = feats(1, 1000, 9).data;
        for len in [1usize, 7, 8, 9, 64, 1000] {
            for tau in [0.01f32, 0.1, 1.0, 7.5] {
                let mut row: Vec<f32> = f[..len].iter().map(|v| v * 3.0 - 1.5).collect();
                if len > 8 {
                    row[3] = f32::NEG_INFINITY;
                    row[5] = -1e30;
                }
                let (_, mx) = row_max(&row).unwrap();
                let want = row_p_scalar(&row, mx, 1.0 / tau);
                assert_eq!(row_p(&row, mx, 1.0 / tau).to_bits(), want.to_bits());
                #[cfg(target_arch = "x86_64")]
                if crate::simd::features().avx2 {
                    let got = unsafe { crate::fusion::avx2::inv_exp_sum(&row, mx, 1.0 / tau) };
                    assert_eq!(got.to_bits(), want.to_bits(), "len {len} tau {tau}");
                    row[0] = f32::NAN;
                    let want = row_p_scalar(&row, mx, 1.0 / tau);
                    let got = unsafe { crate::fusion::avx2::inv_exp_sum(&row, mx, 1.0 / tau) };
                    assert!(got.is_nan() && want.is_nan(), "NaN, len {len}");
                }
            }
        }
        let (a, b) = (feats(300, 33, 3), feats(517, 33, 4));
        let sim = crate::fusion::cosine_similarity(&a, &b).unwrap();
        let maxima = row_maxima(&sim);
        for tau in [0.05f32, 0.1, 0.12] {
            let x = row_nn_from_similarity(&sim, tau).unwrap();
            let y = row_nn_from_maxima(&sim, &maxima, tau).unwrap();
            assert_eq!(x.len(), y.len());
            for (p, q) in x.iter().zip(&y) {
                assert_eq!(
                    (p.src, p.tgt, p.score.to_bits()),
                    (q.src, q.tgt, q.score.to_bits())
                );
            }
        }
        assert!(row_nn_from_maxima(&sim, &maxima[1..], 0.1).is_err());
    }

    /// The streamed row NN against brute force bit for bit: every similarity an FMA chain
    /// written out, then `max_lanes`, the first position and `row_p_scalar`. Shapes leave every
    /// edge of the fused kernel (rows mod 8 and past a band, columns mod 32, mod 8, fewer
    /// than 32) and of the band path; rows with planted ties, a zero row, a NaN row. Repro:
    /// `CGENREG_TEST_SEED=<seed>` (printed on failure).
    #[test]
    fn streamed_row_nn_is_brute_force_bit_for_bit() {
        let (seed, mut rng) = crate::estimate::rng::seeded_for_test("streamed-row-nn");
        for (case, (n, m, d)) in [
            (8, 32, 33),
            (139, 517, 33),
            (17, 7, 33),
            (300, 64, 5),
            (9, 1000, 32),
            (3, 41, 33),
        ]
        .into_iter()
        .enumerate()
        {
            // non-negative like FPFH, quantised so that ties occur
            let mut q = |k: usize| {
                let v: Vec<f32> = (0..k)
                    .map(|_| (rng.unit_f64() * 8.0).floor() as f32 / 8.0)
                    .collect();
                v
            };
            let mut src = Features::new(d, q(n * d));
            let mut tgt = Features::new(d, q(m * d));
            if n > 2 {
                src.data[..d].iter_mut().for_each(|v| *v = 0.0);
                src.data[d..2 * d].iter_mut().for_each(|v| *v = f32::NAN);
            }
            if m > 3 {
                // two equal targets: ties in every row
                let (x, y) = tgt.data.split_at_mut(2 * d);
                y[..d].copy_from_slice(&x[d..2 * d]);
            }
            for tau in [0.1f32, 0.03] {
                let got = row_nn_posterior(&src, &tgt, tau).unwrap();
                let (a, b) = (normalize_rows(&src), normalize_rows(&tgt));
                let mut want = Vec::new();
                for i in 0..n {
                    let row: Vec<f32> = (0..m)
                        .map(|j| {
                            let mut acc = 0.0f32;
                            for k in 0..d {
                                acc = a.data[i * d + k].mul_add(b.data[j * d + k], acc);
                            }
                            acc
                        })
                        .collect();
                    let mx = crate::fusion::calibrate::max_lanes(&row);
                    if !mx.is_finite() {
                        continue;
                    }
                    let j = row.iter().position(|&v| v == mx).unwrap();
                    want.push(Correspondence {
                        src: i as u32,
                        tgt: j as u32,
                        score: row_p_scalar(&row, mx, 1.0 / tau),
                    });
                }
                want.sort_unstable_by(crate::fusion::select::order);
                assert_eq!(got.len(), want.len(), "seed {seed} case {case} tau {tau}");
                for (x, y) in got.iter().zip(&want) {
                    assert_eq!(
                        (x.src, x.tgt, x.score.to_bits()),
                        (y.src, y.tgt, y.score.to_bits()),
                        "seed {seed} case {case} ({n} x {m} x {d}) tau {tau}"
                    );
                }
            }
        }
    }

    #[test]
    fn equals_the_dense_path() {
        for (n, m, d, tau) in [
            (300, 500, 33, 0.1f32),
            (1000, 257, 8, 0.05),
            (5, 3, 33, 1.0),
        ] {
            let (a, b) = (feats(n, d, 1), feats(m, d, 2));
            let fast = row_nn_posterior(&a, &b, tau).unwrap();
            let sim = crate::fusion::cosine_similarity(&a, &b).unwrap();
            let p = FusionParams {
                calibration_geo: Calibration::RowSoftmax { tau },
                mode: FusionMode::GeometryOnly,
                selection: Selection::RowNn,
                ..Default::default()
            };
            let dense = match_then_fuse(None, Some(&sim), &p)
                .unwrap()
                .correspondences;
            let kept = row_nn_from_similarity(&sim, tau).unwrap();
            assert_eq!(fast.len(), dense.len());
            assert_eq!(kept.len(), dense.len());
            for (x, y) in kept.iter().zip(&dense) {
                assert_eq!((x.src, x.tgt), (y.src, y.tgt));
                assert!((x.score - y.score).abs() <= 1e-5 * y.score.max(1e-6));
            }
            for (x, y) in fast.iter().zip(&dense) {
                assert_eq!((x.src, x.tgt), (y.src, y.tgt));
                assert!(
                    (x.score - y.score).abs() <= 1e-5 * y.score.max(1e-6),
                    "{x:?} {y:?}"
                );
            }
        }
    }

    #[test]
    fn rejects_bad_input() {
        assert!(row_nn_posterior(&feats(3, 4, 1), &feats(3, 5, 1), 0.1).is_err());
        assert!(row_nn_posterior(&feats(3, 4, 1), &feats(3, 4, 1), 0.0).is_err());
        let sim = crate::matrix::DenseMatrix::zeros(2, 2).unwrap();
        assert!(row_nn_from_similarity(&sim, f32::NAN).is_err());
        assert!(
            row_nn_posterior(&Features::new(4, vec![]), &feats(3, 4, 1), 0.1)
                .unwrap()
                .is_empty()
        );
    }
}
