//! The estimator's ranked hypotheses for one registration (the inspector's hypothesis
//! browser): the estimator re-run on the result's correspondences with
//! [`estimate_pose_with_hypotheses`] (deterministic: the same estimate, checked), and each
//! hypothesis's RRE / RTE against the ground truth. The registration itself never collects
//! them, so the default path pays nothing.

use super::params::RegisterParams;
use super::result::RegistrationResult;
use crate::error::{Error, Result};
use crate::estimate::{estimate_pose_with_hypotheses, Hypotheses};
use crate::metrics::{rre_deg, rte_m};
use nalgebra::{Isometry3, Point3};

/// Below this ratio of its second to its first principal spread, a consensus set is
/// near-collinear: the points fix no rotation about their line, so the pose fitted to them
/// (and a refinement started from it) is not determined by the data.
pub const COLLINEAR_RATIO: f64 = 0.05;

/// The spread of a point set: the ratios of its second and third principal standard
/// deviations to its first (1, 1: a ball; ~0, ~0: a line; x, ~0: a plane). None for fewer
/// than 3 points or all points equal.
pub fn spread_ratios(points: &[Point3<f32>]) -> Option<(f64, f64)> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let mean = points
        .iter()
        .fold(nalgebra::Vector3::<f64>::zeros(), |a, p| {
            a + p.coords.cast::<f64>()
        })
        / n;
    let mut c = nalgebra::Matrix3::<f64>::zeros();
    for p in points {
        let d = p.coords.cast::<f64>() - mean;
        c += d * d.transpose();
    }
    let mut s: Vec<f64> = c
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .map(|x| (x.max(0.0) / n).sqrt())
        .collect();
    s.sort_by(|a, b| b.total_cmp(a));
    (s[0] > 0.0).then(|| (s[1] / s[0], s[2] / s[0]))
}

/// Whether a consensus set cannot determine a pose: fewer than 3 points, or near-collinear.
pub fn is_degenerate(points: &[Point3<f32>]) -> bool {
    spread_ratios(points).is_none_or(|(r2, _)| r2 < COLLINEAR_RATIO)
}

/// The hypotheses with their errors against the ground truth.
#[derive(Clone, Debug)]
pub struct RankedHypotheses {
    pub hypotheses: Hypotheses,
    /// Per entry of `hypotheses.list`: (RRE degrees, RTE metres) of its pose; None without GT.
    pub vs_gt: Vec<Option<(f64, f64)>>,
}

/// The best `top_n` hypotheses of `params.estimator` on `res`'s correspondences (`res` must
/// have been computed with `params`). None when the estimator forms no hypotheses (weighted
/// SVD, or SC2-PCR's fallback to it). An error when the re-run does not reproduce `res`'s
/// estimate (it is deterministic; this guards the inputs).
pub fn estimator_hypotheses(
    res: &RegistrationResult,
    params: &RegisterParams,
    gt: Option<&Isometry3<f64>>,
    top_n: usize,
) -> Result<Option<RankedHypotheses>> {
    let mut sp: Vec<Point3<f32>> = Vec::with_capacity(res.correspondences.len());
    let mut tp: Vec<Point3<f32>> = Vec::with_capacity(res.correspondences.len());
    for c in &res.correspondences {
        match (
            res.source_keypoints.get(c.src as usize),
            res.target_keypoints.get(c.tgt as usize),
        ) {
            (Some(s), Some(t)) => {
                sp.push(*s);
                tp.push(*t);
            }
            _ => {
                return Err(Error::Shape(format!(
                    "hypotheses: correspondence {} -> {} is outside the keypoints",
                    c.src, c.tgt
                )))
            }
        }
    }
    let w: Vec<f32> = res.correspondences.iter().map(|c| c.score).collect();
    let (est, hyps) =
        estimate_pose_with_hypotheses(&sp, &tp, &w, &params.estimator_resolved(), top_n)?;
    if est.target_from_source != res.estimate {
        return Err(Error::Invalid(format!(
            "hypotheses: re-running {} gave another pose than the registration's ({}); the \
             parameters differ from those of the result",
            res.estimator, est.method
        )));
    }
    Ok(hyps.map(|h| {
        let vs_gt = h
            .list
            .iter()
            .map(|x| gt.map(|g| (rre_deg(&x.pose, g), rte_m(&x.pose, g))))
            .collect();
        RankedHypotheses {
            hypotheses: h,
            vs_gt,
        }
    }))
}

#[cfg(test)]
mod shape_tests {
    use super::*;

    #[test]
    fn collinear_consensus_sets_are_degenerate() {
        let line: Vec<Point3<f32>> = (0..6)
            .map(|i| Point3::new(i as f32, 0.01 * (i % 2) as f32, 0.0))
            .collect();
        assert!(is_degenerate(&line));
        let plane: Vec<Point3<f32>> = (0..9)
            .map(|i| Point3::new((i % 3) as f32, (i / 3) as f32, 0.0))
            .collect();
        let (r2, r3) = spread_ratios(&plane).unwrap();
        assert!((r2 - 1.0).abs() < 1e-6 && r3 < 1e-6);
        assert!(!is_degenerate(&plane));
        assert!(is_degenerate(&plane[..2]));
    }
}
