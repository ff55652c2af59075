//! The numbers registration papers report on the standard benchmarks, per scene and pooled per
//! benchmark: registration recall under the RRE / RTE criterion (SC2-PCR, GeoTransformer), the
//! official 3DMatch recall (RMSE < 0.2 m over the gt.info information matrix, as the 3DMatch
//! toolbox and Predator's `benchmark.py` compute it), and the mean and median RE / TE over the
//! registered pairs.

use super::{mean, median, SuccessCriterion};
use nalgebra::{Isometry3, Matrix6, UnitQuaternion, Vector6};
use serde::{Deserialize, Serialize};

/// The official 3DMatch recall threshold on the RMSE (m).
pub const RMSE_RECALL_M: f64 = 0.2;

/// 3DMatch's RMSE of an estimate against the ground truth (Choi et al.'s approximation of the
/// RMSE of corresponding points): with `Δ = inv(T_gt) · T_est`, `ε = [t_Δ; q_Δ.xyz]` (the
/// quaternion with a non-negative real part) and Σ the gt.info information matrix,
/// `RMSE = sqrt(εᵀ Σ ε / Σ₀₀)`. A pair registers when RMSE < 0.2 m ([`RMSE_RECALL_M`]).
pub fn rmse_3dmatch(est: &Isometry3<f64>, gt: &Isometry3<f64>, info: &Matrix6<f64>) -> f64 {
    let d = gt.inverse() * est;
    let q: UnitQuaternion<f64> = d.rotation;
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    let t = d.translation.vector;
    let e = Vector6::new(t.x, t.y, t.z, s * q.i, s * q.j, s * q.k);
    let p = (e.transpose() * info * e)[(0, 0)] / info[(0, 0)];
    p.max(0.0).sqrt()
}

/// Whether the official 3DMatch recall counts a gt.log pair `i j`: only fragments that are not
/// consecutive (`j - i > 1`), as the 3DMatch evaluation does (consecutive fragments are
/// registered by odometry alone).
pub fn rmse_counts(target: usize, source: usize) -> bool {
    source.abs_diff(target) > 1
}

/// One pair as the field's tables need it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldPair {
    /// Infinite for a pair that ran with an error.
    pub rre_deg: f64,
    pub rte_m: f64,
    /// Under the headline criterion.
    pub success: bool,
    /// Under the second criterion, when the run has one.
    pub also_success: Option<bool>,
    /// `Some` when the official recall counts the pair: its RMSE, infinite when it has no pose.
    pub rmse_m: Option<f64>,
}

/// One row of a paper-style table: a scene of a benchmark, or a benchmark pooled over its
/// pairs (`scene` None). Means and medians of RE / TE are over the registered pairs (under the
/// headline criterion), as SC2-PCR and GeoTransformer report them; NaN (null) when none is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldSummary {
    pub benchmark: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<String>,
    pub pairs: usize,
    pub criterion: SuccessCriterion,
    pub registered: usize,
    /// The registration recall under `criterion` (a fraction; `recall` in files of the first
    /// version).
    #[serde(alias = "recall", deserialize_with = "super::null_as_nan")]
    pub rr: f64,
    /// The second criterion and the fraction of pairs it registers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub also: Option<(SuccessCriterion, f64)>,
    /// Pairs the official RMSE recall counts, and the fraction with RMSE < 0.2 m (None: no
    /// pair has a gt.info entry).
    #[serde(default)]
    pub rmse_pairs: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rmse_recall: Option<f64>,
    #[serde(deserialize_with = "super::null_as_nan")]
    pub re_mean_deg: f64,
    #[serde(deserialize_with = "super::null_as_nan")]
    pub re_median_deg: f64,
    #[serde(deserialize_with = "super::null_as_nan")]
    pub te_mean_m: f64,
    #[serde(deserialize_with = "super::null_as_nan")]
    pub te_median_m: f64,
}

impl FieldSummary {
    pub fn from_pairs(
        benchmark: &str,
        scene: Option<&str>,
        criterion: SuccessCriterion,
        also: Option<SuccessCriterion>,
        pairs: &[FieldPair],
    ) -> FieldSummary {
        let n = pairs.len();
        let ok: Vec<&FieldPair> = pairs.iter().filter(|p| p.success).collect();
        let frac = |k: usize, of: usize| if of == 0 { 0.0 } else { k as f64 / of as f64 };
        let rmse: Vec<f64> = pairs.iter().filter_map(|p| p.rmse_m).collect();
        let re: Vec<f64> = ok.iter().map(|p| p.rre_deg).collect();
        let te: Vec<f64> = ok.iter().map(|p| p.rte_m).collect();
        FieldSummary {
            benchmark: benchmark.to_string(),
            scene: scene.map(str::to_string),
            pairs: n,
            criterion,
            registered: ok.len(),
            rr: frac(ok.len(), n),
            also: also.map(|c| {
                let k = pairs
                    .iter()
                    .filter(|p| p.also_success == Some(true))
                    .count();
                (c, frac(k, n))
            }),
            rmse_pairs: rmse.len(),
            rmse_recall: (!rmse.is_empty()).then(|| {
                frac(
                    rmse.iter().filter(|&&r| r < RMSE_RECALL_M).count(),
                    rmse.len(),
                )
            }),
            re_mean_deg: mean(&re),
            re_median_deg: median(&re),
            te_mean_m: mean(&te),
            te_median_m: median(&te),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, Vector3};

    /// The RMSE against brute force: gt.info is Σ = Σ_k [I, -[p_k]×]ᵀ [I, -[p_k]×] over the
    /// fragment's points (Choi et al.), so εᵀ Σ ε / Σ₀₀ approximates the mean squared
    /// displacement of the points under a small error; checked on a small motion, where the
    /// first-order model holds.
    #[test]
    fn rmse_matches_point_displacement_for_small_errors() {
        let pts: Vec<Vector3<f64>> = (0..200)
            .map(|k| {
                let f = k as f64;
                Vector3::new(
                    (f * 0.37).sin(),
                    (f * 0.11).cos() * 1.5,
                    1.0 + (f * 0.05).sin(),
                )
            })
            .collect();
        let mut info = Matrix6::zeros();
        for p in &pts {
            let mut j = nalgebra::Matrix3x6::zeros();
            j.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&nalgebra::Matrix3::identity());
            // d(R p)/d(q.xyz) at identity: -2 [p]x  (R ≈ I + 2 [q.xyz]x)
            j.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&(-2.0 * p.cross_matrix()));
            info += j.transpose() * j;
        }
        let gt = Isometry3::from_parts(
            Translation3::new(0.5, -0.2, 0.1),
            UnitQuaternion::from_euler_angles(0.3, -0.1, 0.7),
        );
        let err = Isometry3::from_parts(
            Translation3::new(0.01, -0.02, 0.015),
            UnitQuaternion::from_euler_angles(0.004, 0.01, -0.006),
        );
        let est = gt * err;
        let brute = (pts
            .iter()
            .map(|p| (err.transform_vector(p) + err.translation.vector - p).norm_squared())
            .sum::<f64>()
            / pts.len() as f64)
            .sqrt();
        let r = rmse_3dmatch(&est, &gt, &info);
        assert!((r - brute).abs() < 0.02 * brute, "{r} vs {brute}");
        assert!(rmse_3dmatch(&gt, &gt, &info) < 1e-12);
        // the sign of the quaternion does not matter
        let flipped = Isometry3::from_parts(
            est.translation,
            UnitQuaternion::new_unchecked(-est.rotation.into_inner()),
        );
        assert!((rmse_3dmatch(&flipped, &gt, &info) - r).abs() < 1e-12);
        assert!(rmse_counts(0, 2) && !rmse_counts(3, 4) && !rmse_counts(4, 3));
    }

    #[test]
    fn summary_means_are_over_registered_pairs() {
        let p = |rre: f64, rte: f64, ok: bool, rmse: Option<f64>| FieldPair {
            rre_deg: rre,
            rte_m: rte,
            success: ok,
            also_success: Some(ok && rte < 0.1),
            rmse_m: rmse,
        };
        let s = FieldSummary::from_pairs(
            "3DMatch",
            None,
            SuccessCriterion::THREEDMATCH,
            Some(SuccessCriterion::SC2PCR_KITTI),
            &[
                p(2.0, 0.05, true, Some(0.05)),
                p(4.0, 0.15, true, None),
                p(90.0, 2.0, false, Some(1.5)),
                p(f64::INFINITY, f64::INFINITY, false, Some(f64::INFINITY)),
            ],
        );
        assert_eq!((s.pairs, s.registered, s.rmse_pairs), (4, 2, 3));
        assert!((s.rr - 0.5).abs() < 1e-12);
        assert!((s.rmse_recall.unwrap() - 1.0 / 3.0).abs() < 1e-12);
        assert!((s.re_mean_deg - 3.0).abs() < 1e-12 && (s.te_median_m - 0.1).abs() < 1e-12);
        assert!((s.also.unwrap().1 - 0.25).abs() < 1e-12);
        let none = FieldSummary::from_pairs("x", None, SuccessCriterion::KITTI, None, &[]);
        assert!(none.re_mean_deg.is_nan() && none.rmse_recall.is_none() && none.rr == 0.0);
    }
}
