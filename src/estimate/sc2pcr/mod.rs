//! SC2-PCR (Chen et al., CVPR 2022) exactly as the C-GenReg reference calls it
//! (reference §9.2, `models/SC2PCR/SC2_PCR_MY.py`), with bs = 1.
//!
//! Input: correspondence endpoints `src[i] ↔ tgt[i]` (source and target frames), sorted by score
//! descending; the first `max_points` are used. Output: `target_from_source`.
//!
//! The reference builds several dense N x N f32 matrices (N = 8000: 256 MB each). Here:
//! - `hard = C < d`, `tight = C < d/2` and `near = Ds < nms_radius` are bitsets (u64 words);
//! - `SC = clamp(1 − C²/d², 0)` is non-zero exactly where `hard` is set, so it is stored as one
//!   (column, value) pair per set bit of `hard` (a sparse row);
//! - `SC2[s, j] = popcount(tight[s] & tight[j])` for `hard[s, j]`, 0 otherwise, is evaluated only
//!   for the set bits of `hard[s]`, visited by decreasing upper bound `|tight[j]|` so the scan
//!   stops once nothing left can enter the top-k1; only the top-k1 are kept.
//!
//! Ties are broken deterministically by the lower correspondence index (stable sorts); torch's
//! unstable argsort may order ties differently. By default the correspondences used (the first
//! `max_points`) run in a canonical order ([`canonical_order`]), so the result is a function of
//! their set: the order by score only decides which are used. With
//! [`Sc2PcrParams::score_order`] (what `--reference` sets) they run in the order given, the
//! fused-score order, as the reference does: most seeds tie (at zero after NMS) and the tied
//! seeds, tied top-k entries and the first maximum of the hypothesis scores then resolve by
//! score rank as in the authors' code instead of by position.
//!
//! Files: this one holds the algorithm (`sc2pcr`, the per-seed weights, the post-refinement);
//! `graph.rs` the compatibility graph (bitsets, SC matvec, leading eigenvector, NMS seeds,
//! SC2 top-k); `soa.rs` the endpoints as structure-of-arrays; the per-ISA compatibility-row and
//! popcount kernels are in `crate::simd`.

mod graph;
mod soa;
#[cfg(test)]
mod tests;

use super::hypotheses::{Hypotheses, Hypothesis, TopN};
use super::kabsch;
use super::scale::{Scaled, REFERENCE_VOXEL, THRESHOLD_PER_VOXEL};
use super::Estimate;
use crate::{Error, Result};
use graph::Graph;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
pub(crate) use soa::Soa;

/// Reference §9.1 (upstream `config_3DMatch.json`). The two distances follow the keypoint
/// voxel by default ([`super::scale`]: 2 v, 0.10 m at 3DMatch's 0.05 m, 0.6 m at KITTI's
/// 0.3 m); the pipeline resolves them ([`Sc2PcrParams::resolved`]) before it runs SC2-PCR.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sc2PcrParams {
    /// Hypothesis scoring and post-refinement inlier threshold (m). The reference refines with
    /// 0.10 for 3DMatch and 1.2 for KITTI; here refinement uses this value.
    pub inlier_threshold: Scaled<f32>,
    /// Compatibility distance d (m): `hard = C < d`, `tight = C < d/2`.
    pub d_thre: Scaled<f32>,
    /// Power-iteration steps (global eigenvector and per-seed weights).
    pub num_iterations: usize,
    /// Fraction of correspondences taken as seeds.
    pub ratio: f32,
    /// NMS radius in the source cloud (m).
    pub nms_radius: f32,
    pub max_points: usize,
    pub k1: usize,
    pub k2: usize,
    pub refine_iterations: usize,
    /// Run the correspondences in the order given (by score, as the reference does) instead
    /// of the canonical coordinate order: ties then resolve as in the authors' code.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub score_order: bool,
}

impl Default for Sc2PcrParams {
    fn default() -> Self {
        Sc2PcrParams {
            inlier_threshold: Scaled::FollowVoxel,
            d_thre: Scaled::FollowVoxel,
            num_iterations: 10,
            ratio: 0.2,
            nms_radius: 0.10,
            max_points: 8000,
            k1: 30,
            k2: 20,
            refine_iterations: 20,
            score_order: false,
        }
    }
}

impl Sc2PcrParams {
    /// A copy with both distances set to their values at `voxel`.
    pub fn resolved(&self, voxel: f64) -> Sc2PcrParams {
        Sc2PcrParams {
            inlier_threshold: self.inlier_threshold.resolved(voxel, THRESHOLD_PER_VOXEL),
            d_thre: self.d_thre.resolved(voxel, THRESHOLD_PER_VOXEL),
            ..self.clone()
        }
    }
}

/// The parameters as the algorithm reads them: both distances in metres.
#[derive(Clone, Debug)]
struct Resolved {
    inlier_threshold: f32,
    d_thre: f32,
    num_iterations: usize,
    ratio: f32,
    nms_radius: f32,
    k1: usize,
    k2: usize,
    refine_iterations: usize,
    score_order: bool,
}

/// Run SC2-PCR. Errors (which `estimate_pose` turns into the weighted-SVD fallback, as the
/// reference does on an exception): mismatched lengths, non-finite coordinates, fewer than 5
/// correspondences (no seed or no 4-neighbourhood), invalid parameters.
pub fn sc2pcr(src: &[Point3<f32>], tgt: &[Point3<f32>], params: &Sc2PcrParams) -> Result<Estimate> {
    sc2pcr_with(src, tgt, params, 0).map(|(e, _)| e)
}

/// [`sc2pcr`] that also keeps the best `top_n` seed hypotheses (None when `top_n` is 0),
/// ranked by SC2-PCR's own rule: consensus size (correspondences within `inlier_threshold`
/// under the seed's pose), ties to the earlier seed (the reference's argmax takes the first
/// maximum). Rank 1 is the hypothesis post-refined into the estimate, which is the same as
/// [`sc2pcr`]'s.
pub fn sc2pcr_with(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    params: &Sc2PcrParams,
    top_n: usize,
) -> Result<(Estimate, Option<Hypotheses>)> {
    if src.len() != tgt.len() {
        return Err(Error::Shape(format!(
            "sc2pcr: {} source points but {} target points",
            src.len(),
            tgt.len()
        )));
    }
    // called without a voxel (outside the pipeline): SC2-PCR's own 3DMatch configuration
    let p = &Resolved {
        inlier_threshold: params
            .inlier_threshold
            .at(REFERENCE_VOXEL, THRESHOLD_PER_VOXEL),
        d_thre: params.d_thre.at(REFERENCE_VOXEL, THRESHOLD_PER_VOXEL),
        num_iterations: params.num_iterations,
        ratio: params.ratio,
        nms_radius: params.nms_radius,
        k1: params.k1,
        k2: params.k2,
        refine_iterations: params.refine_iterations,
        score_order: params.score_order,
    };
    let max_points = params.max_points;
    if !(p.d_thre > 0.0 && p.inlier_threshold > 0.0 && p.nms_radius >= 0.0 && p.ratio > 0.0)
        || p.k1 == 0
        || p.k2 == 0
        || max_points == 0
    {
        return Err(Error::Param(format!("sc2pcr: invalid parameters {p:?}")));
    }
    let n = src.len().min(max_points);
    let (src, tgt) = (&src[..n], &tgt[..n]);
    if let Some(i) = (0..n).find(|&i| {
        !(src[i].coords.iter().all(|v| v.is_finite())
            && tgt[i].coords.iter().all(|v| v.is_finite()))
    }) {
        return Err(Error::Degenerate(format!(
            "sc2pcr: correspondence {i} has a non-finite coordinate"
        )));
    }
    let (mut k1, mut k2) = (p.k1, p.k2.min(p.k1));
    if k1 > n {
        k1 = 4;
        k2 = 4;
    }
    let num_seeds = ((n as f64) * (p.ratio as f64)).floor() as usize;
    if n < 4 || k1 > n || num_seeds == 0 {
        return Err(Error::Degenerate(format!(
            "sc2pcr: {n} correspondences are too few (need {k1} neighbours and at least one seed)"
        )));
    }
    // The first `n` run in the canonical order, so that the result depends on which are used,
    // not on their order (a temperature change under NN selection reorders the same set);
    // in score order when asked (the reference's tie-breaking).
    if p.score_order {
        return run(src, tgt, p, top_n, (k1, k2), num_seeds);
    }
    let o = canonical_order(src, tgt);
    let (s, t): (Vec<_>, Vec<_>) = o.iter().map(|&i| (src[i], tgt[i])).unzip();
    let (e, hyps) = run(&s, &t, p, top_n, (k1, k2), num_seeds)?;
    Ok((e.reindexed(&o), hyps.map(|h| h.reindexed(&o))))
}

/// The order SC2-PCR runs its correspondences in (the first `max_points` given):
/// lexicographic in the source then target coordinates (`f32::total_cmp`), equal endpoints in
/// their given order. `order[k]` is the input index of the k-th correspondence run.
pub fn canonical_order(src: &[Point3<f32>], tgt: &[Point3<f32>]) -> Vec<usize> {
    let key = |i: usize| [src[i].x, src[i].y, src[i].z, tgt[i].x, tgt[i].y, tgt[i].z];
    let mut order: Vec<usize> = (0..src.len().min(tgt.len())).collect();
    order.sort_by(|&a, &b| {
        let (ka, kb) = (key(a), key(b));
        (0..6).fold(std::cmp::Ordering::Equal, |o, k| {
            o.then_with(|| ka[k].total_cmp(&kb[k]))
        })
    });
    order
}

/// SC2-PCR on `src`/`tgt` in the order given (validated by [`sc2pcr_with`]).
fn run(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    p: &Resolved,
    top_n: usize,
    (k1, k2): (usize, usize),
    num_seeds: usize,
) -> Result<(Estimate, Option<Hypotheses>)> {
    let n = src.len();
    let pts = Soa::new(src, tgt);
    let g = Graph::build(&pts, p.d_thre, p.nms_radius);
    let conf = g.leading_eigenvector(p.num_iterations);
    let seeds = g.pick_seeds(&conf, num_seeds);
    // Blocks of seeds share each tight row they load (8 seed rows stay in L1 at n = 8000).
    let sets = seeds
        .par_chunks(8)
        .flat_map_iter(|block| {
            g.sc2_top_k_block(block, k1)
                .into_iter()
                .map(|knn| g.second_stage(&knn, k2))
        })
        .collect::<Vec<_>>();
    let weights = seed_weights(&pts, &sets, p.d_thre, p.num_iterations);
    let hyps: Vec<Option<Isometry3<f64>>> = sets
        .par_iter()
        .zip(weights.par_iter())
        .map(|(set, w)| {
            kabsch::solve(
                set.len(),
                |k| (pts.src64(set[k]), pts.tgt64(set[k]), w[k] as f64),
                1e-6,
            )
        })
        .collect();
    let fitness: Vec<usize> = hyps
        .par_iter()
        .map(|h| {
            h.as_ref()
                .map_or(0, |t| pts.count_inliers(t, p.inlier_threshold))
        })
        .collect();
    // argmax returns the first maximum, like torch.
    let mut best: Option<(usize, usize)> = None;
    for (k, h) in hyps.iter().enumerate() {
        if h.is_some() && best.is_none_or(|(_, f)| fitness[k] > f) {
            best = Some((k, fitness[k]));
        }
    }
    let Some((best, _)) = best else {
        return Err(Error::Degenerate(
            "sc2pcr: no seed gave a finite transform".into(),
        ));
    };
    let mut trans = hyps[best].unwrap_or_else(Isometry3::identity);
    trans = post_refinement(&pts, trans, p.inlier_threshold, p.refine_iterations);
    let d = pts.residuals(&trans);
    let inliers: Vec<usize> = (0..n).filter(|&i| d[i] < p.inlier_threshold).collect();
    let warning = inlier_warning("sc2pcr", &pts, &inliers);
    let ranked = (top_n > 0).then(|| {
        // (seed position, consensus) by the rule above: the winner `best` comes first
        let mut top = TopN::new(top_n);
        let better = |a: &(usize, usize), b: &(usize, usize)| a.1 > b.1 || a.1 == b.1 && a.0 < b.0;
        for (k, h) in hyps.iter().enumerate() {
            if h.is_some() {
                top.push((k, fitness[k]), better);
            }
        }
        Hypotheses {
            estimator: "sc2pcr".into(),
            rule: format!(
                "consensus size: correspondences within {:.3} m under the seed's pose, ties to \
                 the earlier seed; the best is post-refined ({} iterations) into the estimate",
                p.inlier_threshold, p.refine_iterations
            ),
            threshold_m: p.inlier_threshold as f64,
            total: hyps.iter().filter(|h| h.is_some()).count(),
            list: top
                .into_vec()
                .into_iter()
                .enumerate()
                .map(|(r, (k, f))| {
                    let pose = hyps[k].unwrap_or_else(Isometry3::identity);
                    let d = pts.residuals(&pose);
                    Hypothesis {
                        rank: r + 1,
                        sample: vec![seeds[k]],
                        consensus: f,
                        sse: None,
                        pose,
                        inliers: (0..n).filter(|&i| d[i] < p.inlier_threshold).collect(),
                        winner: k == best,
                    }
                })
                .collect(),
            refined: trans,
        }
    });
    Ok((
        Estimate {
            target_from_source: trans,
            inliers,
            method: "sc2pcr".into(),
            warning,
        },
        ranked,
    ))
}

/// A warning when the inlier set cannot pin down a pose: fewer than 3, or identical or
/// collinear source or target points.
pub(crate) fn inlier_warning(who: &str, p: &Soa, inliers: &[usize]) -> Option<String> {
    if inliers.len() < 3 {
        return Some(format!(
            "{who}: only {} of {} correspondences agree with the estimate",
            inliers.len(),
            p.n
        ));
    }
    for (name, f) in [
        ("source", Soa::src64 as fn(&Soa, usize) -> Vector3<f64>),
        ("target", Soa::tgt64),
    ] {
        if let Some(what) = kabsch::spread_problem(inliers.len(), |k| (f(p, inliers[k]), 1.0)) {
            return Some(format!(
                "{who}: the {} inlier {name} points are {what}; the pose is not determined",
                inliers.len()
            ));
        }
    }
    None
}

/// torch.allclose defaults: |a − b| ≤ 1e-8 + 1e-5 |b|.
fn allclose(a: &[f32], b: &[f32]) -> bool {
    a.iter()
        .zip(b)
        .all(|(&x, &y)| (x - y).abs() <= 1e-8 + 1e-5 * y.abs())
}

/// `v / (‖v‖ + 1e-6)`.
fn normalise(v: &mut [f32]) {
    let norm = v
        .iter()
        .map(|&x| (x as f64) * (x as f64))
        .sum::<f64>()
        .sqrt() as f32;
    let s = norm + 1e-6;
    for x in v {
        *x /= s;
    }
}

/// Per-seed weights: leading eigenvector of `M = clamp(1 − C²/d², 0)` with zero diagonal over
/// the k2 set, normalised to sum 1 (+1e-6). The reference runs all seeds as one batch, so its
/// early stop (allclose) fires only when every seed has converged; that is reproduced here.
pub(crate) fn seed_weights(
    p: &Soa,
    sets: &[Vec<usize>],
    d: f32,
    iterations: usize,
) -> Vec<Vec<f32>> {
    let d2 = d * d;
    // Per seed: the iterates and whether each was allclose to its predecessor.
    let hist: Vec<(Vec<Vec<f32>>, Vec<bool>)> = sets
        .par_iter()
        .map(|set| {
            let k = set.len();
            let mut m = vec![0f32; k * k];
            for a in 0..k {
                for b in 0..k {
                    if a != b {
                        let (_, c) = p.cross(set[a], set[b]);
                        m[a * k + b] = (1.0 - c * c / d2).max(0.0);
                    }
                }
            }
            let mut v = vec![1f32; k];
            let mut iters = Vec::with_capacity(iterations);
            let mut close = Vec::with_capacity(iterations);
            for _ in 0..iterations {
                let mut y: Vec<f32> = (0..k)
                    .map(|a| (0..k).map(|b| m[a * k + b] * v[b]).sum())
                    .collect();
                normalise(&mut y);
                close.push(allclose(&y, &v));
                v = y.clone();
                iters.push(y);
            }
            (iters, close)
        })
        .collect();
    let last = iterations.saturating_sub(1);
    let stop = (0..iterations)
        .find(|&t| hist.iter().all(|(_, c)| c[t]))
        .unwrap_or(last);
    hist.into_iter()
        .zip(sets)
        .map(|((iters, _), set)| {
            let mut w = iters
                .get(stop)
                .cloned()
                .unwrap_or_else(|| vec![1f32; set.len()]);
            let s: f32 = w.iter().sum::<f32>() + 1e-6;
            for x in &mut w {
                *x /= s;
            }
            w
        })
        .collect()
}

/// Reference `post_refinement`: re-solve on the inliers with weights 1/(1 + (d/thr)²) until the
/// inlier count stops changing, at most `iterations` times.
fn post_refinement(
    p: &Soa,
    mut trans: Isometry3<f64>,
    thr: f32,
    iterations: usize,
) -> Isometry3<f64> {
    let mut previous = 0usize;
    for _ in 0..iterations {
        let d = p.residuals(&trans);
        let inl: Vec<usize> = (0..p.n).filter(|&i| d[i] < thr).collect();
        if inl.len() == previous || inl.len() < 3 {
            break;
        }
        previous = inl.len();
        let w = |i: usize| 1.0 / (1.0 + ((d[i] / thr) as f64).powi(2));
        match kabsch::solve(
            inl.len(),
            |k| (p.src64(inl[k]), p.tgt64(inl[k]), w(inl[k])),
            1e-6,
        ) {
            Some(t) => trans = t,
            None => break,
        }
    }
    trans
}
