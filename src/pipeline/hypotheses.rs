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
                return Err(Error::Invalid(format!(
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
