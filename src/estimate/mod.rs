//! Rigid pose estimation from correspondences: weighted Kabsch, SC2-PCR, RANSAC.
//!
//! Every estimator takes correspondence endpoints `src[i] ↔ tgt[i]` (source and target frames)
//! and returns `target_from_source` (`tgt[i] ≈ T * src[i]` for inliers).

pub mod hypotheses;
pub mod kabsch;
pub mod nonrigid;
pub mod ransac;
pub(crate) mod rng;
pub mod sc2pcr;
pub mod scale;
pub mod synthetic;

use crate::{Error, Result};
pub use hypotheses::{Hypotheses, Hypothesis};
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion};
pub use ransac::RansacParams;
pub use sc2pcr::Sc2PcrParams;

/// The result of an estimator. `inliers` index the correspondence list given to it.
#[derive(Clone, Debug)]
pub struct Estimate {
    pub target_from_source: Isometry3<f64>,
    pub inliers: Vec<usize>,
    /// Which estimator actually produced the pose (e.g. "sc2pcr" or "weighted-svd fallback").
    pub method: String,
    /// Set when the result should not be trusted (degenerate input, fallback used, ...).
    pub warning: Option<String>,
}

impl Estimate {
    /// The estimate of a run on the correspondences `order[0], order[1], ...` with its inlier
    /// indices turned back into input indices (ascending).
    pub(crate) fn reindexed(mut self, order: &[usize]) -> Self {
        self.inliers = hypotheses::reindex(&self.inliers, order);
        self
    }
}

/// Which estimator `estimate_pose` runs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum EstimatorKind {
    /// SC2-PCR, falling back to weighted SVD when it fails (reference §9.2 step 10).
    Sc2Pcr(Sc2PcrParams),
    Ransac(RansacParams),
    /// Weighted SVD over all correspondences, weights = scores (the reference fallback).
    WeightedSvd,
}

impl Default for EstimatorKind {
    fn default() -> Self {
        EstimatorKind::Sc2Pcr(Sc2PcrParams::default())
    }
}

impl EstimatorKind {
    /// Every estimator with its default parameters.
    pub fn all() -> [EstimatorKind; 3] {
        [
            EstimatorKind::Sc2Pcr(Sc2PcrParams::default()),
            EstimatorKind::Ransac(RansacParams::default()),
            EstimatorKind::WeightedSvd,
        ]
    }

    pub fn label(&self) -> &'static str {
        match self {
            EstimatorKind::Sc2Pcr(_) => "SC2-PCR",
            EstimatorKind::Ransac(_) => "RANSAC",
            EstimatorKind::WeightedSvd => "Weighted SVD",
        }
    }

    /// A copy with every distance that follows the keypoint voxel set to its value at `voxel`
    /// ([`scale`]): what the pipeline runs and keys.
    pub fn resolved(&self, voxel: f64) -> EstimatorKind {
        match self {
            EstimatorKind::Sc2Pcr(p) => EstimatorKind::Sc2Pcr(p.resolved(voxel)),
            EstimatorKind::Ransac(p) => EstimatorKind::Ransac(p.resolved(voxel)),
            EstimatorKind::WeightedSvd => EstimatorKind::WeightedSvd,
        }
    }

    /// Whether `self` and `other` are the same estimator (parameters aside).
    pub fn same_kind(&self, other: &EstimatorKind) -> bool {
        std::mem::discriminant(self) == std::mem::discriminant(other)
    }

    /// The distance (m) within which a correspondence agrees with this estimator's pose.
    pub fn inlier_threshold(&self) -> f64 {
        match self {
            // resolved parameters hold metres; unresolved ones read at SC2-PCR's own voxel
            EstimatorKind::Sc2Pcr(p) => {
                p.inlier_threshold
                    .at(scale::REFERENCE_VOXEL, scale::THRESHOLD_PER_VOXEL) as f64
            }
            EstimatorKind::Ransac(p) => {
                p.distance_threshold
                    .at(scale::REFERENCE_VOXEL, scale::RANSAC_PER_VOXEL) as f64
            }
            EstimatorKind::WeightedSvd => 0.10,
        }
    }
}

/// `e` with the [`nonrigid::nonrigid_warning`] added when no rigid transform explains the
/// correspondences.
fn with_rigidity_check(
    mut e: Estimate,
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    method: &EstimatorKind,
) -> Estimate {
    let (pose, thr) = (&e.target_from_source, method.inlier_threshold());
    let found = nonrigid::nonrigid_warning(src, tgt, pose, thr)
        .or_else(|| nonrigid::low_consensus_warning(src, tgt, pose, thr));
    if let Some(w) = found {
        e.warning = Some(match e.warning.take() {
            Some(first) => format!("{first}; {w}"),
            None => w,
        });
    }
    e
}

/// `--estimator sc2pcr|ransac|svd`, each with its default parameters.
impl clap::ValueEnum for EstimatorKind {
    fn value_variants<'a>() -> &'a [Self] {
        static V: std::sync::LazyLock<[EstimatorKind; 3]> =
            std::sync::LazyLock::new(EstimatorKind::all);
        &*V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(match self {
            EstimatorKind::Sc2Pcr(_) => "sc2pcr",
            EstimatorKind::Ransac(_) => "ransac",
            EstimatorKind::WeightedSvd => "svd",
        }))
    }
}

/// Estimate `target_from_source` from scored correspondences (`weights[i]` is the score of
/// `src[i] ↔ tgt[i]`; SC2-PCR and RANSAC only use it in the fallback).
///
/// When SC2-PCR fails the reference falls back to weighted SVD; so does this function, and then
/// `method` is "weighted-svd (fallback)" and `warning` says why. Degenerate input that also
/// defeats the fallback (fewer than 3 correspondences, identical or collinear points) is an
/// `Error::Degenerate`.
pub fn estimate_pose(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    weights: &[f32],
    method: &EstimatorKind,
) -> Result<Estimate> {
    if src.len() != tgt.len() || weights.len() != src.len() {
        return Err(Error::Shape(format!(
            "estimate_pose: {} source points, {} target points, {} weights",
            src.len(),
            tgt.len(),
            weights.len()
        )));
    }
    let e = match method {
        EstimatorKind::Sc2Pcr(p) => match sc2pcr::sc2pcr(src, tgt, p) {
            Ok(e) => e,
            Err(err) => {
                let mut e = weighted_svd(src, tgt, weights)?;
                e.method = "weighted-svd (fallback)".into();
                e.warning = Some(format!("SC2-PCR failed ({err}); weighted SVD used instead"));
                e
            }
        },
        EstimatorKind::Ransac(p) => ransac::ransac(src, tgt, p)?,
        EstimatorKind::WeightedSvd => weighted_svd(src, tgt, weights)?,
    };
    Ok(with_rigidity_check(e, src, tgt, method))
}

/// [`estimate_pose`] that also returns the estimator's best `top_n` hypotheses, ranked by its
/// own rule (SC2-PCR: seeds by consensus size; RANSAC: its inlier count, then squared error).
/// The estimate is the same as [`estimate_pose`]'s. None: weighted SVD (one solution, no
/// hypotheses), SC2-PCR's fallback to it, or `top_n` 0.
pub fn estimate_pose_with_hypotheses(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    weights: &[f32],
    method: &EstimatorKind,
    top_n: usize,
) -> Result<(Estimate, Option<Hypotheses>)> {
    match method {
        EstimatorKind::Sc2Pcr(p) if src.len() == tgt.len() && weights.len() == src.len() => {
            match sc2pcr::sc2pcr_with(src, tgt, p, top_n) {
                Ok((e, h)) => Ok((with_rigidity_check(e, src, tgt, method), h)),
                // the fallback, exactly as estimate_pose words it
                Err(_) => estimate_pose(src, tgt, weights, method).map(|e| (e, None)),
            }
        }
        EstimatorKind::Ransac(p) if src.len() == tgt.len() && weights.len() == src.len() => {
            ransac::ransac_with(src, tgt, p, top_n)
                .map(|(e, h)| (with_rigidity_check(e, src, tgt, method), h))
        }
        _ => estimate_pose(src, tgt, weights, method).map(|e| (e, None)),
    }
}

/// The reference `weighted_svd`: weights clamped to ≥ 0 and divided by (Σw + 1e-5), weighted
/// Kabsch, then R re-orthonormalised (Gram-Schmidt). Inliers are the correspondences within
/// 0.10 m under the result.
pub fn weighted_svd(src: &[Point3<f32>], tgt: &[Point3<f32>], weights: &[f32]) -> Result<Estimate> {
    if src.len() != tgt.len() || weights.len() != src.len() {
        return Err(Error::Shape(format!(
            "weighted_svd: {} source points, {} target points, {} weights",
            src.len(),
            tgt.len(),
            weights.len()
        )));
    }
    let w: Vec<f64> = weights
        .iter()
        .map(|&x| {
            if x.is_finite() {
                x.max(0.0) as f64
            } else {
                0.0
            }
        })
        .collect();
    let s: f64 = w.iter().sum::<f64>() + 1e-5;
    let w: Vec<f64> = w.iter().map(|x| x / s).collect();
    let s64: Vec<Point3<f64>> = src.iter().map(|p| p.cast()).collect();
    let t64: Vec<Point3<f64>> = tgt.iter().map(|p| p.cast()).collect();
    let est = kabsch::weighted_kabsch(&s64, &t64, Some(&w))?;
    let r = est.rotation.to_rotation_matrix().into_inner();
    let r = kabsch::orthonormalise(&r)
        .ok_or_else(|| Error::Degenerate("weighted_svd: rotation is degenerate".into()))?;
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    // Keep the translation consistent with the cleaned rotation about the weighted centroids.
    let (mut cs, mut ct) = (nalgebra::Vector3::zeros(), nalgebra::Vector3::zeros());
    for i in 0..src.len() {
        cs += w[i] * s64[i].coords;
        ct += w[i] * t64[i].coords;
    }
    let ws: f64 = w.iter().sum();
    let t = ct / ws - rot * (cs / ws);
    let tf = Isometry3::from_parts(Translation3::from(t), rot);
    let inliers = (0..src.len())
        .filter(|&i| (tf * s64[i] - t64[i]).norm() < 0.10)
        .collect();
    Ok(Estimate {
        target_from_source: tf,
        inliers,
        method: "weighted-svd".into(),
        warning: None,
    })
}

#[cfg(test)]
mod tests {
    use super::synthetic::synthetic_correspondences;
    use super::*;
    use crate::metrics::{rre_deg, rte_m};

    #[test]
    fn falls_back_to_weighted_svd_when_sc2pcr_fails() {
        // 4 exact correspondences: too few for SC2-PCR, enough for weighted SVD.
        let data = synthetic_correspondences(100, 4, 1.0, 0.0, 9);
        let est =
            estimate_pose(&data.src, &data.tgt, &[1.0; 4], &EstimatorKind::default()).unwrap();
        assert_eq!(est.method, "weighted-svd (fallback)");
        assert!(est.warning.as_deref().unwrap().contains("SC2-PCR failed"));
        assert!(rre_deg(&est.target_from_source, &data.target_from_source) < 1e-3);
        assert!(rte_m(&est.target_from_source, &data.target_from_source) < 1e-4);
    }

    #[test]
    fn weighted_svd_uses_the_scores() {
        let data = synthetic_correspondences(500, 200, 0.5, 0.0, 10);
        let w: Vec<f32> = data
            .is_inlier
            .iter()
            .map(|&b| if b { 0.9 } else { -0.2 })
            .collect();
        let est = estimate_pose(&data.src, &data.tgt, &w, &EstimatorKind::WeightedSvd).unwrap();
        assert!(rre_deg(&est.target_from_source, &data.target_from_source) < 1e-3);
        // Every true match is an inlier (an outlier may fall within 10 cm by chance).
        let true_in = est.inliers.iter().filter(|&&i| data.is_inlier[i]).count();
        assert_eq!(true_in, 100);
        assert!(est.inliers.len() <= 103);
    }

    #[test]
    fn degenerate_input_is_an_error_not_a_panic() {
        let p = |x: f32| Point3::new(x, 2.0 * x, 0.5);
        let line: Vec<_> = (0..10).map(|i| p(i as f32 * 0.1)).collect();
        for kind in [
            EstimatorKind::default(),
            EstimatorKind::WeightedSvd,
            EstimatorKind::Ransac(RansacParams::default()),
        ] {
            for (s, t) in [
                (&line[..2], &line[..2]),
                (&line[..], &line[..]),
                (&[p(1.0); 10][..], &[p(1.0); 10][..]),
            ] {
                let w = vec![1.0; s.len()];
                match estimate_pose(s, t, &w, &kind) {
                    Err(Error::Degenerate(_)) => {}
                    Ok(e) => assert!(e.warning.is_some(), "{kind:?}: unflagged {e:?}"),
                    Err(e) => panic!("{kind:?}: unexpected error {e}"),
                }
            }
        }
        assert!(matches!(
            estimate_pose(&line, &line[..3], &[1.0; 10], &EstimatorKind::WeightedSvd),
            Err(Error::Shape(_))
        ));
    }
}
