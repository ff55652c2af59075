//! Correspondence selection from a score matrix: mutual nearest neighbours (paper), global
//! top-k (reference §8.5, k = 8000), or each source point's nearest target (SC2-PCR's FPFH
//! protocol).
//!
//! Entries with score <= 0 (invalid, or a vetoed pair) and NaN are never selected. The result
//! is sorted by (score descending, source, target), so ties have a deterministic order.

use super::Correspondence;
use crate::matrix::{rows_per_task, DenseMatrix};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::cmp::Ordering;

/// Which correspondences to keep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Selection {
    #[default]
    /// (i, j) where j is the best target of row i and i the best source of column j.
    MutualNn,
    /// The k best entries of the whole matrix; a point may appear many times.
    TopK(usize),
    /// Every source point with its best target (no mutual check): the feature-matching
    /// protocol of PointDSC / SC2-PCR for FPFH, where the robust estimator removes outliers.
    RowNn,
}

/// The reference's number of matches.
pub const REFERENCE_TOP_K: usize = 8000;

impl Selection {
    /// The selection a run uses unless one is chosen, the same in `register`, `bench`, the
    /// inspector and Python: each source keypoint's best target for geometry alone (the SC2-PCR
    /// FPFH protocol), mutual nearest neighbours when the branches are fused (the paper).
    pub fn default_for(image_branch: bool) -> Selection {
        if image_branch {
            Selection::MutualNn
        } else {
            Selection::RowNn
        }
    }

    /// Every rule; top-k with `k`.
    pub fn all_with_k(k: usize) -> [Selection; 3] {
        [Selection::MutualNn, Selection::TopK(k), Selection::RowNn]
    }

    pub fn label(&self) -> &'static str {
        match self {
            Selection::MutualNn => "Mutual nearest",
            Selection::TopK(_) => "Top-k by score",
            Selection::RowNn => "Best target per source",
        }
    }
}

/// `--selection mutual|topk|nn`; top-k's k comes from `--topk`.
impl clap::ValueEnum for Selection {
    fn value_variants<'a>() -> &'a [Self] {
        const V: [Selection; 3] = [
            Selection::MutualNn,
            Selection::TopK(REFERENCE_TOP_K),
            Selection::RowNn,
        ];
        &V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        use clap::builder::PossibleValue;
        Some(match self {
            Selection::MutualNn => PossibleValue::new("mutual")
                .help("Mutual nearest neighbours of the fused posterior (paper)"),
            Selection::TopK(_) => {
                PossibleValue::new("topk").help("Global top-k entries (reference code, k = 8000)")
            }
            Selection::RowNn => PossibleValue::new("nn")
                .help("Each source point's best target, no mutual check (SC2-PCR's FPFH protocol)"),
        })
    }
}

/// Selects correspondences from `scores` (module docs for the rules).
pub fn select(scores: &DenseMatrix, sel: Selection) -> Vec<Correspondence> {
    // A matrix whose buffer disagrees with its shape is read only as far as it is consistent.
    let cols = scores.cols;
    if cols == 0 || scores.rows == 0 {
        return Vec::new();
    }
    let rows = scores.rows.min(scores.data.len() / cols);
    let data = &scores.data[..rows * cols];
    let mut out = match sel {
        Selection::MutualNn => mutual_nn(data, rows, cols),
        Selection::TopK(k) => top_k(data, rows, cols, k),
        Selection::RowNn => data
            .par_chunks(cols)
            .enumerate()
            .filter_map(|(i, row)| {
                row_argmax(row).map(|(j, s)| Correspondence {
                    src: i as u32,
                    tgt: j as u32,
                    score: s,
                })
            })
            .collect(),
    };
    out.sort_unstable_by(order);
    out
}

pub(crate) fn order(a: &Correspondence, b: &Correspondence) -> Ordering {
    b.score
        .total_cmp(&a.score)
        .then(a.src.cmp(&b.src))
        .then(a.tgt.cmp(&b.tgt))
}

/// First index of the row maximum, if that maximum is > 0.
fn row_argmax(row: &[f32]) -> Option<(usize, f32)> {
    let mx = super::calibrate::max_lanes(row);
    if mx > 0.0 {
        row.iter().position(|&v| v == mx).map(|j| (j, mx))
    } else {
        None
    }
}

fn mutual_nn(data: &[f32], rows: usize, cols: usize) -> Vec<Correspondence> {
    // One pass: row argmax and running column maxima per band of rows. Each fold scans
    // consecutive bands in order, folds are reduced in order and only a strictly greater score
    // replaces the current best, so column ties go to the lowest row (as row ties go to the
    // lowest column in `row_argmax`).
    let band = rows_per_task(rows, cols, 1 << 16);
    let mut best_tgt: Vec<Option<(usize, f32)>> = vec![None; rows];
    let (_, cidx) = data
        .par_chunks(band * cols)
        .zip(best_tgt.par_chunks_mut(band))
        .enumerate()
        .fold(
            || (vec![0.0f32; cols], vec![u32::MAX; cols]),
            |(mut cb, mut ci), (t, (chunk, bt))| {
                for (k, (row, b)) in chunk.chunks(cols).zip(bt.iter_mut()).enumerate() {
                    let i = (t * band + k) as u32;
                    for ((v, b), c) in row.iter().zip(cb.iter_mut()).zip(ci.iter_mut()) {
                        let better = *v > *b;
                        *b = if better { *v } else { *b };
                        *c = if better { i } else { *c };
                    }
                    *b = row_argmax(row);
                }
                (cb, ci)
            },
        )
        .reduce_with(|(mut cb, mut ci), (cb2, ci2)| {
            for j in 0..cols {
                if cb2[j] > cb[j] {
                    cb[j] = cb2[j];
                    ci[j] = ci2[j];
                }
            }
            (cb, ci)
        })
        .unwrap_or_else(|| (vec![0.0; cols], vec![u32::MAX; cols]));
    best_tgt
        .iter()
        .enumerate()
        .filter_map(|(i, b)| {
            let (j, s) = (*b)?;
            (cidx[j] == i as u32).then_some(Correspondence {
                src: i as u32,
                tgt: j as u32,
                score: s,
            })
        })
        .collect()
}

/// Candidate order: score descending, then flat index ascending (a strict total order).
fn cand_order(a: &(f32, u64), b: &(f32, u64)) -> Ordering {
    b.0.total_cmp(&a.0).then(a.1.cmp(&b.1))
}

/// Keeps the k best of `buf` under `cand_order`; returns the worst kept score.
fn prune(buf: &mut Vec<(f32, u64)>, k: usize) -> f32 {
    if buf.len() > k {
        buf.select_nth_unstable_by(k - 1, cand_order);
        buf.truncate(k);
    }
    buf.iter().map(|c| c.0).fold(f32::INFINITY, f32::min)
}

fn top_k(data: &[f32], rows: usize, cols: usize, k: usize) -> Vec<Correspondence> {
    if k == 0 {
        return Vec::new();
    }
    let band = rows_per_task(rows, cols, 1 << 16);
    // Each fold scans its entries in ascending flat index, so once it holds k candidates a new
    // entry with a score equal to the k-th one ranks below it: admitting only `s > thr` is exact.
    let mut cands = data
        .par_chunks(band * cols)
        .enumerate()
        .fold(
            || (Vec::<(f32, u64)>::new(), 0.0f32),
            |(mut buf, mut thr), (t, chunk)| {
                let base = (t * band * cols) as u64;
                for (q, block) in chunk.chunks(64).enumerate() {
                    if super::calibrate::max_lanes(block) <= thr {
                        continue;
                    }
                    for (r, &s) in block.iter().enumerate() {
                        if s > thr {
                            buf.push((s, base + (q * 64 + r) as u64));
                        }
                    }
                    if buf.len() >= 2 * k.max(512) {
                        thr = thr.max(prune(&mut buf, k));
                    }
                }
                (buf, thr)
            },
        )
        .map(|(mut buf, _)| {
            prune(&mut buf, k);
            buf
        })
        .reduce_with(|mut a, b| {
            a.extend(b);
            prune(&mut a, k);
            a
        })
        .unwrap_or_default();
    prune(&mut cands, k);
    cands
        .into_iter()
        .map(|(s, idx)| Correspondence {
            src: (idx / cols as u64) as u32,
            tgt: (idx % cols as u64) as u32,
            score: s,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Lcg;

    /// Scores with many exact ties, zeros and a few negatives.
    fn tied_matrix(rows: usize, cols: usize, seed: u64) -> DenseMatrix {
        let mut s = Lcg(seed);
        DenseMatrix::from_fn(rows, cols, |_, _| match s.u31() % 10 {
            0 => 0.0,
            1 => -0.5,
            r => (s.u31() % 7) as f32 * 0.125 + r as f32 * 0.01,
        })
        .unwrap()
    }

    fn brute_mutual(m: &DenseMatrix) -> Vec<Correspondence> {
        let mut out = vec![];
        for i in 0..m.rows {
            let mut bj = None;
            for j in 0..m.cols {
                let v = m.get(i, j);
                if v > 0.0 && bj.is_none_or(|b: usize| v > m.get(i, b)) {
                    bj = Some(j);
                }
            }
            let Some(j) = bj else { continue };
            let mut bi = 0;
            for q in 0..m.rows {
                if m.get(q, j) > m.get(bi, j) {
                    bi = q;
                }
            }
            if bi == i {
                out.push(Correspondence {
                    src: i as u32,
                    tgt: j as u32,
                    score: m.get(i, j),
                });
            }
        }
        out.sort_by(order);
        out
    }

    fn brute_topk(m: &DenseMatrix, k: usize) -> Vec<Correspondence> {
        let mut all: Vec<Correspondence> = (0..m.rows)
            .flat_map(|i| (0..m.cols).map(move |j| (i, j)))
            .filter(|&(i, j)| m.get(i, j) > 0.0)
            .map(|(i, j)| Correspondence {
                src: i as u32,
                tgt: j as u32,
                score: m.get(i, j),
            })
            .collect();
        all.sort_by(order);
        all.truncate(k);
        all
    }

    #[test]
    fn mutual_nn_matches_brute_force() {
        for (rows, cols, seed) in [(50, 70, 1), (300, 40, 2), (7, 900, 3), (1, 1, 4)] {
            let m = tied_matrix(rows, cols, seed);
            assert_eq!(
                select(&m, Selection::MutualNn),
                brute_mutual(&m),
                "{rows}x{cols}"
            );
        }
        // A permutation with distinct scores is recovered entirely.
        let n = 64;
        let m = DenseMatrix::from_fn(n, n, |i, j| if j == (i * 7 + 3) % n { 0.9 } else { 0.1 })
            .unwrap();
        let c = select(&m, Selection::MutualNn);
        assert_eq!(c.len(), n);
        assert!(c
            .iter()
            .all(|c| c.tgt as usize == (c.src as usize * 7 + 3) % n));
    }

    #[test]
    fn top_k_matches_brute_force() {
        for (rows, cols, seed, k) in [
            (50, 70, 1, 100),
            (300, 400, 2, 8000),
            (300, 400, 5, 3),
            (20, 20, 3, 10_000),
        ] {
            let m = tied_matrix(rows, cols, seed);
            assert_eq!(
                select(&m, Selection::TopK(k)),
                brute_topk(&m, k),
                "{rows}x{cols} k={k}"
            );
        }
        let m = tied_matrix(10, 10, 9);
        assert!(select(&m, Selection::TopK(0)).is_empty());
        let zero = DenseMatrix::zeros(5, 5).unwrap();
        assert!(select(&zero, Selection::TopK(10)).is_empty());
        assert!(select(&zero, Selection::MutualNn).is_empty());
        let mut nan = tied_matrix(5, 5, 1);
        nan.data.iter_mut().for_each(|v| *v = f32::NAN);
        assert!(select(&nan, Selection::TopK(10)).is_empty());
        assert!(select(&DenseMatrix::zeros(0, 3).unwrap(), Selection::MutualNn).is_empty());
    }

    #[test]
    fn row_nn_matches_brute_force() {
        for (rows, cols, seed) in [(50, 70, 1), (300, 40, 2), (7, 900, 3)] {
            let m = tied_matrix(rows, cols, seed);
            let mut brute = vec![];
            for i in 0..m.rows {
                let mut bj: Option<usize> = None;
                for j in 0..m.cols {
                    let v = m.get(i, j);
                    if v > 0.0 && bj.is_none_or(|b| v > m.get(i, b)) {
                        bj = Some(j);
                    }
                }
                if let Some(j) = bj {
                    brute.push(Correspondence {
                        src: i as u32,
                        tgt: j as u32,
                        score: m.get(i, j),
                    });
                }
            }
            brute.sort_by(order);
            assert_eq!(select(&m, Selection::RowNn), brute, "{rows}x{cols}");
        }
    }
}
