//! RANSAC over correspondences, as Open3D's `registration_ransac_based_on_correspondence` with
//! the checkers of its global-registration example: 3-point hypotheses, an edge-length checker
//! (ratio 0.9) before the fit, a distance checker after it, fitness = inlier fraction, ties broken
//! by the lower inlier RMSE, and the confidence-based early stop
//! `k = log(1 − confidence) / log(1 − fitness³)`. The best hypothesis is finally refitted
//! (least squares, twice) on its inliers.
//!
//! Hypothesis k draws its sample from its own PCG32 stream (seed, k), and hypotheses run in
//! chunks whose best is reduced by a total order, so the result does not depend on the number
//! of threads.

use super::hypotheses::{Hypotheses, Hypothesis, TopN};
use super::kabsch;
use super::rng::Pcg32;
use super::sc2pcr::{inlier_warning, Soa};
use super::scale::{Scaled, RANSAC_PER_VOXEL, REFERENCE_VOXEL};
use super::Estimate;
use crate::{Error, Result};
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RansacParams {
    pub max_iterations: usize,
    /// Inlier distance (m). Default: follows the keypoint voxel at 1.5 v, the rule of Open3D's
    /// global-registration example (0.075 m at a 5 cm voxel); called without a voxel, 0.075 m.
    pub distance_threshold: Scaled<f32>,
    /// Early-stop confidence in (0, 1]; 1 never stops early (runs `max_iterations`).
    pub confidence: f64,
    pub seed: u64,
}

impl RansacParams {
    /// A copy with the inlier distance set to its value at `voxel`.
    pub fn resolved(&self, voxel: f64) -> RansacParams {
        RansacParams {
            distance_threshold: self.distance_threshold.resolved(voxel, RANSAC_PER_VOXEL),
            ..self.clone()
        }
    }
}

impl Default for RansacParams {
    fn default() -> Self {
        RansacParams {
            max_iterations: 100_000,
            distance_threshold: Scaled::FollowVoxel,
            confidence: 0.999,
            seed: 0,
        }
    }
}

const EDGE_RATIO: f32 = 0.9;
const CHUNK: usize = 1024;

#[derive(Clone, Copy)]
struct Hyp {
    inliers: usize,
    sse: f64,
    k: usize,
    t: Isometry3<f64>,
}

/// `a` better than `b`: more inliers, then lower squared error, then the earlier hypothesis.
fn better(a: &Hyp, b: &Hyp) -> bool {
    if a.inliers != b.inliers {
        return a.inliers > b.inliers;
    }
    if a.sse != b.sse {
        return a.sse < b.sse;
    }
    a.k < b.k
}

pub fn ransac(src: &[Point3<f32>], tgt: &[Point3<f32>], params: &RansacParams) -> Result<Estimate> {
    ransac_with(src, tgt, params, 0).map(|(e, _)| e)
}

/// [`ransac`] that also keeps its best `top_n` hypotheses (None when `top_n` is 0), ranked by
/// RANSAC's own order: more inliers, then the lower sum of squared inlier residuals, then the
/// earlier hypothesis. Rank 1 is the hypothesis refitted into the estimate. The estimate is
/// the same as [`ransac`]'s.
pub fn ransac_with(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    params: &RansacParams,
    top_n: usize,
) -> Result<(Estimate, Option<Hypotheses>)> {
    if src.len() != tgt.len() {
        return Err(Error::Shape(format!(
            "ransac: {} source points but {} target points",
            src.len(),
            tgt.len()
        )));
    }
    let n = src.len();
    if n < 3 {
        return Err(Error::Degenerate(format!(
            "ransac: need at least 3 correspondences, got {n}"
        )));
    }
    let thr = params
        .distance_threshold
        .at(REFERENCE_VOXEL, RANSAC_PER_VOXEL);
    let valid = thr > 0.0 && params.confidence > 0.0 && params.confidence <= 1.0;
    if !valid {
        return Err(Error::Param(format!(
            "ransac: invalid parameters {params:?}"
        )));
    }
    if let Some(i) = (0..n).find(|&i| {
        !(src[i].coords.iter().all(|v| v.is_finite())
            && tgt[i].coords.iter().all(|v| v.is_finite()))
    }) {
        return Err(Error::Degenerate(format!(
            "ransac: correspondence {i} has a non-finite coordinate"
        )));
    }
    let p = Soa::new(src, tgt);
    let mut best: Option<Hyp> = None;
    let mut limit = params.max_iterations;
    let mut done = 0usize;
    let mut top = TopN::new(top_n);
    let mut scored = 0usize;
    while done < limit {
        let end = (done + CHUNK).min(limit);
        let hyps = (done..end)
            .into_par_iter()
            .filter_map(|k| hypothesis(&p, src, tgt, params.seed, k, thr));
        let chunk_best = if top_n == 0 {
            hyps.reduce_with(|a, b| if better(&b, &a) { b } else { a })
        } else {
            // the same best (a total order), and the chunk's hypotheses for the top list
            let all: Vec<Hyp> = hyps.collect();
            scored += all.len();
            for h in &all {
                top.push(*h, better);
            }
            all.into_iter()
                .reduce(|a, b| if better(&b, &a) { b } else { a })
        };
        if let Some(c) = chunk_best {
            if best.is_none_or(|b| better(&c, &b)) {
                best = Some(c);
            }
        }
        done = end;
        if let Some(b) = best {
            let fitness = b.inliers as f64 / n as f64;
            let est = (1.0 - params.confidence).ln() / (1.0 - fitness.powi(3)).ln();
            if est.is_finite() && est >= 0.0 {
                limit = limit.min(est.ceil() as usize);
            } else if fitness >= 1.0 {
                limit = done;
            }
        }
    }
    let Some(b) = best else {
        return Err(Error::Degenerate(format!(
            "ransac: none of {done} hypotheses passed the edge-length and distance checks"
        )));
    };
    // Final least-squares refit on the inliers of the best hypothesis (twice, re-selecting the
    // inliers in between): a 3-point fit carries the full noise of its sample.
    let mut t = b.t;
    for _ in 0..2 {
        let (_, inl) = score(&p, &t, thr, true);
        if inl.len() < 3 {
            break;
        }
        match kabsch::solve(inl.len(), |k| (p.src64(inl[k]), p.tgt64(inl[k]), 1.0), 0.0) {
            Some(r) => t = r,
            None => break,
        }
    }
    let (_, inliers) = score(&p, &t, thr, true);
    let warning = inlier_warning("ransac", &p, &inliers);
    let hyps = (top_n > 0).then(|| Hypotheses {
        estimator: "ransac".into(),
        rule: format!(
            "RANSAC's order: more inliers within {:.3} m, then the lower sum of squared inlier \
             residuals, then the earlier hypothesis; the best is refitted (least squares, \
             twice) into the estimate",
            thr
        ),
        threshold_m: thr as f64,
        total: scored,
        list: top
            .into_vec()
            .into_iter()
            .enumerate()
            .map(|(r, h)| Hypothesis {
                rank: r + 1,
                sample: sample(params.seed, h.k, n).to_vec(),
                consensus: h.inliers,
                sse: Some(h.sse),
                pose: h.t,
                inliers: score(&p, &h.t, thr, true).1,
                winner: h.k == b.k,
            })
            .collect(),
        refined: t,
    });
    Ok((
        Estimate {
            target_from_source: t,
            inliers,
            method: format!("ransac ({done} hypotheses)"),
            warning,
        },
        hyps,
    ))
}

/// The 3 distinct correspondences of hypothesis `k` (its own PCG32 stream).
fn sample(seed: u64, k: usize, n: usize) -> [usize; 3] {
    let n = n as u32;
    let mut rng = Pcg32::new(seed, k as u64);
    let a = rng.below(n);
    let mut b = rng.below(n - 1);
    if b >= a {
        b += 1;
    }
    let mut c = rng.below(n - 2);
    let (lo, hi) = (a.min(b), a.max(b));
    if c >= lo {
        c += 1;
    }
    if c >= hi {
        c += 1;
    }
    [a as usize, b as usize, c as usize]
}

fn hypothesis(
    p: &Soa,
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    seed: u64,
    k: usize,
    thr: f32,
) -> Option<Hyp> {
    let idx = sample(seed, k, src.len());
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let ds = (src[idx[i]] - src[idx[j]]).norm();
        let dt = (tgt[idx[i]] - tgt[idx[j]]).norm();
        if !(ds >= dt * EDGE_RATIO && dt >= ds * EDGE_RATIO) {
            return None;
        }
    }
    let t = kabsch::solve(3, |m| (p.src64(idx[m]), p.tgt64(idx[m]), 1.0), 0.0)?;
    for &i in &idx {
        if (t * src[i].cast::<f64>() - tgt[i].cast::<f64>()).norm() >= thr as f64 {
            return None;
        }
    }
    let ((inliers, sse), _) = score(p, &t, thr, false);
    Some(Hyp { inliers, sse, k, t })
}

/// Inlier count and sum of squared inlier distances (and the inlier list when asked).
fn score(p: &Soa, t: &Isometry3<f64>, thr: f32, list: bool) -> ((usize, f64), Vec<usize>) {
    let d = p.residuals(t);
    let thr2 = thr * thr;
    let mut cnt = [0u32; 8];
    let mut sse = [0f32; 8];
    let chunks = d.len() / 8;
    for c in 0..chunks {
        for l in 0..8 {
            let r = d[c * 8 + l];
            let r2 = r * r;
            let ok = r2 < thr2;
            cnt[l] += ok as u32;
            sse[l] += if ok { r2 } else { 0.0 };
        }
    }
    for &r in d.iter().skip(chunks * 8) {
        let r2 = r * r;
        if r2 < thr2 {
            cnt[0] += 1;
            sse[0] += r2;
        }
    }
    let inl = if list {
        (0..d.len()).filter(|&i| d[i] * d[i] < thr2).collect()
    } else {
        Vec::new()
    };
    (
        (
            cnt.iter().map(|&c| c as usize).sum(),
            sse.iter().map(|&s| s as f64).sum(),
        ),
        inl,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::synthetic::synthetic_correspondences;
    use crate::metrics::{rre_deg, rte_m};

    fn check(ratio: f64, seed: u64) {
        let data = synthetic_correspondences(2000, 2000, ratio, 0.01, seed);
        let prm = RansacParams::default();
        let est = ransac(&data.src, &data.tgt, &prm).unwrap();
        let gt = data.target_from_source;
        let (rre, rte) = (
            rre_deg(&est.target_from_source, &gt),
            rte_m(&est.target_from_source, &gt),
        );
        assert!(
            rre < 2.0 && rte < 0.05,
            "ratio {ratio}: rre {rre} rte {rte}"
        );
        let true_in = est.inliers.iter().filter(|&&i| data.is_inlier[i]).count();
        assert!(true_in as f64 >= 0.9 * est.inliers.len() as f64);
        // Deterministic for a seed.
        let again = ransac(&data.src, &data.tgt, &prm).unwrap();
        assert_eq!(again.target_from_source, est.target_from_source);
        assert_eq!(again.method, est.method);
    }

    #[test]
    fn recovers_pose_at_30_percent_inliers() {
        check(0.3, 31);
    }

    #[test]
    fn recovers_pose_at_10_percent_inliers() {
        check(0.1, 32);
    }

    /// The kept hypotheses are RANSAC's best by its own order, the winner is rank 1 and the
    /// estimate is the same as without them.
    #[test]
    fn hypotheses_ranked_winner_first_same_estimate() {
        let data = synthetic_correspondences(2000, 1500, 0.2, 0.01, 41);
        let prm = RansacParams::default();
        let plain = ransac(&data.src, &data.tgt, &prm).unwrap();
        let (est, h) = ransac_with(&data.src, &data.tgt, &prm, 20).unwrap();
        let h = h.unwrap();
        assert_eq!(est.target_from_source, plain.target_from_source);
        assert_eq!(est.inliers, plain.inliers);
        // the early stop may leave fewer than 20 that passed the checks
        assert!(h.total >= 1);
        assert_eq!(h.list.len(), h.total.min(20));
        assert!(h.list[0].winner && h.list.iter().filter(|x| x.winner).count() == 1);
        assert_eq!(h.refined, est.target_from_source);
        for w in h.list.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            assert!(
                a.consensus > b.consensus
                    || a.consensus == b.consensus && a.sse.unwrap() <= b.sse.unwrap()
            );
        }
        for x in &h.list {
            assert_eq!(x.inliers.len(), x.consensus);
            assert_eq!(x.sample.len(), 3);
        }
        assert!(ransac_with(&data.src, &data.tgt, &prm, 0)
            .unwrap()
            .1
            .is_none());
    }

    #[test]
    fn degenerate_inputs() {
        let p = Point3::new(1.0f32, 1.0, 1.0);
        assert!(matches!(
            ransac(&[p, p], &[p, p], &RansacParams::default()),
            Err(Error::Degenerate(_))
        ));
        // Identical points: every hypothesis passes the checks, but the result is flagged.
        match ransac(&[p; 10], &[p; 10], &RansacParams::default()) {
            Ok(e) => assert!(e.warning.is_some()),
            Err(e) => assert!(matches!(e, Error::Degenerate(_))),
        }
    }
}
