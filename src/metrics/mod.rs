//! Registration metrics as the reference computes them (reference §10): RRE, RTE, inlier ratio,
//! recall, accuracy at thresholds, correspondence precision/recall.
//!
//! Conventions: transforms are `target_from_source`; correspondences are endpoint pairs
//! `src[i] ↔ tgt[i]` in their own frames. RRE is in degrees, RTE in metres.

pub mod convention;
pub mod field;
pub mod overlap;

pub use field::{rmse_3dmatch, FieldPair, FieldSummary};

use crate::{Error, Result};
use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

/// Registration recall thresholds (3DMatch): RRE ≤ 15° and RTE ≤ 0.30 m.
pub const RECALL_RRE_DEG: f64 = 15.0;
pub const RECALL_RTE_M: f64 = 0.30;
/// Inlier-ratio threshold (m).
pub const INLIER_THRESHOLD_M: f64 = 0.10;
/// Correct-match threshold for precision/recall curves (paper fig. 7), metres.
pub const PR_THRESHOLD_M: f64 = 0.05;

/// Relative rotation error `degrees(arccos(clamp((tr(R̂ᵀ R_gt) − 1)/2, −1, 1)))`.
pub fn rre_deg(est: &Isometry3<f64>, gt: &Isometry3<f64>) -> f64 {
    let r_est = est.rotation.to_rotation_matrix().into_inner();
    let r_gt = gt.rotation.to_rotation_matrix().into_inner();
    let c = (((r_est.transpose() * r_gt).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

/// Relative translation error `‖t_gt − t̂‖₂` in metres.
pub fn rte_m(est: &Isometry3<f64>, gt: &Isometry3<f64>) -> f64 {
    (gt.translation.vector - est.translation.vector).norm()
}

/// Distances `‖T_gt src_i − tgt_i‖` of each correspondence under the ground truth.
pub fn gt_residuals(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    gt: &Isometry3<f64>,
) -> Result<Vec<f64>> {
    if src.len() != tgt.len() {
        return Err(Error::Shape(format!(
            "metrics: {} source points but {} target points",
            src.len(),
            tgt.len()
        )));
    }
    Ok(src
        .iter()
        .zip(tgt)
        .map(|(p, q)| (gt * p.cast::<f64>() - q.cast::<f64>()).norm())
        .collect())
}

/// Fraction of correspondences with `‖T_gt p − q‖ ≤ thresh` (the reference uses 0.10 m).
/// 0 for an empty set.
pub fn inlier_ratio(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    gt: &Isometry3<f64>,
    thresh: f64,
) -> Result<f64> {
    let d = gt_residuals(src, tgt, gt)?;
    if d.is_empty() {
        return Ok(0.0);
    }
    Ok(d.iter().filter(|&&x| x <= thresh).count() as f64 / d.len() as f64)
}

/// When a registration counts as a success: RRE ≤ `max_rre_deg` and RTE ≤ `max_rte_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SuccessCriterion {
    pub max_rre_deg: f64,
    pub max_rte_m: f64,
}

impl SuccessCriterion {
    /// 3DMatch registration recall (and the paper's): 15° / 0.30 m.
    pub const THREEDMATCH: SuccessCriterion = SuccessCriterion {
        max_rre_deg: RECALL_RRE_DEG,
        max_rte_m: RECALL_RTE_M,
    };
    /// The KITTI odometry benchmark as GeoTransformer and most KITTI tables score it: 5° / 2 m.
    pub const KITTI: SuccessCriterion = SuccessCriterion {
        max_rre_deg: 5.0,
        max_rte_m: 2.0,
    };
    /// SC2-PCR's own KITTI criterion (`config_KITTI.json`: re_thre 5, te_thre 60 cm).
    pub const SC2PCR_KITTI: SuccessCriterion = SuccessCriterion {
        max_rre_deg: 5.0,
        max_rte_m: 0.6,
    };

    pub fn judge(&self, rre_deg: f64, rte_m: f64) -> bool {
        rre_deg <= self.max_rre_deg && rte_m <= self.max_rte_m
    }

    /// "RRE ≤ 5°, RTE ≤ 2 m": how tables and results name it.
    pub fn label(&self) -> String {
        format!("RRE ≤ {}°, RTE ≤ {} m", self.max_rre_deg, self.max_rte_m)
    }

    /// "5°/2m": a column header.
    pub fn short(&self) -> String {
        format!("{}°/{}m", self.max_rre_deg, self.max_rte_m)
    }
}

impl Default for SuccessCriterion {
    fn default() -> Self {
        SuccessCriterion::THREEDMATCH
    }
}

/// How a run judges success: the headline criterion and, optionally, a second one reported
/// beside it (the outdoor preset: KITTI's 5° / 2 m, with SC2-PCR's 5° / 0.6 m).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SuccessCriteria {
    pub primary: SuccessCriterion,
    #[serde(default)]
    pub also: Option<SuccessCriterion>,
}

/// A pair judged by a criterion.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Judged {
    pub criterion: SuccessCriterion,
    pub success: bool,
}

/// Metrics of one registered pair.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairMetrics {
    pub rre_deg: f64,
    pub rte_m: f64,
    pub inlier_ratio: f64,
    /// Under `criterion`.
    pub success: bool,
    /// The criterion `success` was judged by (results written before it was named: 3DMatch's).
    #[serde(default)]
    pub criterion: SuccessCriterion,
    /// The second criterion of the run, when it has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub also: Option<Judged>,
}

impl PairMetrics {
    /// Judged by 3DMatch's 15° / 0.30 m.
    pub fn new(est: &Isometry3<f64>, gt: &Isometry3<f64>, inlier_ratio: f64) -> Self {
        Self::judged(est, gt, inlier_ratio, &SuccessCriteria::default())
    }

    /// Judged by `criteria`.
    pub fn judged(
        est: &Isometry3<f64>,
        gt: &Isometry3<f64>,
        inlier_ratio: f64,
        criteria: &SuccessCriteria,
    ) -> Self {
        let (rre, rte) = (rre_deg(est, gt), rte_m(est, gt));
        PairMetrics {
            rre_deg: rre,
            rte_m: rte,
            inlier_ratio,
            success: criteria.primary.judge(rre, rte),
            criterion: criteria.primary,
            also: criteria.also.map(|c| Judged {
                criterion: c,
                success: c.judge(rre, rte),
            }),
        }
    }

    /// With the inlier ratio of the correspondences at 0.10 m.
    pub fn compute(
        est: &Isometry3<f64>,
        gt: &Isometry3<f64>,
        src: &[Point3<f32>],
        tgt: &[Point3<f32>],
    ) -> Result<Self> {
        Ok(Self::new(
            est,
            gt,
            inlier_ratio(src, tgt, gt, INLIER_THRESHOLD_M)?,
        ))
    }
}

/// Benchmark summary over pairs, as the reference prints it and the paper tabulates it.
/// Accuracies and recall are fractions in [0, 1] (RRE ≤ 5/10/45°, RTE ≤ 5/10/25 cm). A pair
/// with no pose (infinite error) counts in the fractions; the RRE / RTE means and medians are
/// over the pairs with finite errors. With none, fractions are 0 and means/medians NaN
/// (serialised as null).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub n: usize,
    #[serde(deserialize_with = "null_as_nan")]
    pub recall: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rot_acc_5: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rot_acc_10: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rot_acc_45: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rre_mean: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rre_median: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub trans_acc_5cm: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub trans_acc_10cm: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub trans_acc_25cm: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rte_mean: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub rte_median: f64,
    #[serde(deserialize_with = "null_as_nan")]
    pub ir_mean: f64,
}

/// A number written by serde_json, where NaN is written as `null`, read back (`null` as NaN).
pub(crate) fn null_as_nan<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The finite values: a pair with no pose (infinite error) is a failure in the fractions, but
/// an infinite mean or median says nothing about the pairs that have one.
fn finite(v: &[f64]) -> Vec<f64> {
    v.iter().copied().filter(|x| x.is_finite()).collect()
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// NumPy's median: the mean of the two middle values for an even count.
fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        (s[m - 1] + s[m]) / 2.0
    }
}

fn frac(v: &[f64], t: f64) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        v.iter().filter(|&&x| x <= t).count() as f64 / v.len() as f64
    }
}

impl Summary {
    pub fn from_pairs(pairs: &[PairMetrics]) -> Summary {
        let rre: Vec<f64> = pairs.iter().map(|p| p.rre_deg).collect();
        let rte: Vec<f64> = pairs.iter().map(|p| p.rte_m).collect();
        let ir: Vec<f64> = pairs.iter().map(|p| p.inlier_ratio).collect();
        let recall = if pairs.is_empty() {
            0.0
        } else {
            pairs.iter().filter(|p| p.success).count() as f64 / pairs.len() as f64
        };
        Summary {
            n: pairs.len(),
            recall,
            rot_acc_5: frac(&rre, 5.0),
            rot_acc_10: frac(&rre, 10.0),
            rot_acc_45: frac(&rre, 45.0),
            rre_mean: mean(&finite(&rre)),
            rre_median: median(&finite(&rre)),
            trans_acc_5cm: frac(&rte, 0.05),
            trans_acc_10cm: frac(&rte, 0.10),
            trans_acc_25cm: frac(&rte, 0.25),
            rte_mean: mean(&finite(&rte)),
            rte_median: median(&finite(&rte)),
            ir_mean: mean(&ir),
        }
    }
}

/// One point of a precision/recall curve.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PrPoint {
    /// Matches with score ≥ threshold are predicted.
    pub threshold: f32,
    pub precision: f64,
    pub recall: f64,
}

/// Correspondence precision/recall curve (paper fig. 7).
///
/// A match `src[i] ↔ tgt[i]` is correct when `‖T_gt src_i − tgt_i‖ ≤ thresh` (paper: 5 cm). For
/// every distinct score τ, from the highest down, the predicted set is {i : scores[i] ≥ τ};
/// precision = correct predicted / predicted, recall = correct predicted / `n_gt_matches`.
/// `n_gt_matches` is the number of correct matches available: pass the count over the whole
/// candidate set when `scores` cover only a selection of it; `None` uses the correct matches
/// among the given correspondences, so the last point has recall 1 (when there is any correct
/// match). Recall is 0 when there are no correct matches at all.
pub fn precision_recall(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    scores: &[f32],
    gt: &Isometry3<f64>,
    thresh: f64,
    n_gt_matches: Option<usize>,
) -> Result<Vec<PrPoint>> {
    if scores.len() != src.len() {
        return Err(Error::Shape(format!(
            "precision_recall: {} scores for {} correspondences",
            scores.len(),
            src.len()
        )));
    }
    if let Some(i) = scores.iter().position(|s| s.is_nan()) {
        return Err(Error::Invalid(format!(
            "precision_recall: score {i} is NaN"
        )));
    }
    let d = gt_residuals(src, tgt, gt)?;
    let correct: Vec<bool> = d.iter().map(|&x| x <= thresh).collect();
    let n_gt = n_gt_matches.unwrap_or_else(|| correct.iter().filter(|&&c| c).count());
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    let mut out = Vec::new();
    let mut tp = 0usize;
    for (k, &i) in order.iter().enumerate() {
        tp += correct[i] as usize;
        let last_of_tie = order.get(k + 1).is_none_or(|&j| scores[j] != scores[i]);
        if last_of_tie {
            out.push(PrPoint {
                threshold: scores[i],
                precision: tp as f64 / (k + 1) as f64,
                recall: if n_gt == 0 {
                    0.0
                } else {
                    tp as f64 / n_gt as f64
                },
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn rre_of_a_ten_degree_rotation_is_ten() {
        let gt = Isometry3::identity();
        let est = Isometry3::new(Vector3::zeros(), Vector3::z() * 10f64.to_radians());
        assert!((rre_deg(&est, &gt) - 10.0).abs() < 1e-9);
        // Symmetric, and composed with a common rotation it is unchanged.
        assert!((rre_deg(&gt, &est) - 10.0).abs() < 1e-9);
        let c = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.3, -0.2, 0.9));
        assert!((rre_deg(&(c * est), &c) - 10.0).abs() < 1e-9);
        // 180 degrees is clamped, not NaN.
        let flip = Isometry3::new(Vector3::zeros(), Vector3::x() * std::f64::consts::PI);
        assert!((rre_deg(&flip, &gt) - 180.0).abs() < 1e-6);
    }

    #[test]
    fn rte_and_success_by_hand() {
        let gt = Isometry3::translation(1.0, 0.0, 0.0);
        let est = Isometry3::translation(1.0, 0.3, 0.4);
        assert!((rte_m(&est, &gt) - 0.5).abs() < 1e-12);
        let m = PairMetrics::new(&est, &gt, 0.2);
        assert!(!m.success);
        let est = Isometry3::new(
            Vector3::new(1.0, 0.0, 0.3),
            Vector3::y() * 15f64.to_radians(),
        );
        let m = PairMetrics::new(&est, &gt, 0.2);
        assert!((m.rte_m - 0.3).abs() < 1e-12 && (m.rre_deg - 15.0).abs() < 1e-9);
        let est = Isometry3::new(
            Vector3::new(1.0, 0.0, 0.29),
            Vector3::y() * 14.9f64.to_radians(),
        );
        assert!(PairMetrics::new(&est, &gt, 0.2).success);
        let est = Isometry3::new(
            Vector3::new(1.0, 0.0, 0.29),
            Vector3::y() * 15.1f64.to_radians(),
        );
        assert!(!PairMetrics::new(&est, &gt, 0.2).success);
    }

    #[test]
    fn inlier_ratio_by_hand() {
        let gt = Isometry3::translation(0.0, 0.0, 1.0);
        let src = vec![Point3::new(0.0f32, 0.0, 0.0); 4];
        let tgt = vec![
            Point3::new(0.0f32, 0.0, 1.0),
            Point3::new(0.05, 0.0, 1.0),
            Point3::new(0.0, 0.2, 1.0),
            Point3::new(0.0, 0.0, 1.5),
        ];
        assert_eq!(inlier_ratio(&src, &tgt, &gt, 0.10).unwrap(), 0.5);
        assert_eq!(inlier_ratio(&src, &tgt, &gt, 0.30).unwrap(), 0.75);
        assert_eq!(inlier_ratio(&[], &[], &gt, 0.10).unwrap(), 0.0);
        assert!(inlier_ratio(&src, &tgt[..3], &gt, 0.1).is_err());
    }

    #[test]
    fn success_is_judged_and_named_by_its_criteria() {
        let gt = Isometry3::identity();
        // 4° and 1 m off: a KITTI success, not at SC2-PCR's 0.6 m nor at 3DMatch's 0.30 m
        let est = Isometry3::new(Vector3::x(), Vector3::z() * 4f64.to_radians());
        let outdoor = SuccessCriteria {
            primary: SuccessCriterion::KITTI,
            also: Some(SuccessCriterion::SC2PCR_KITTI),
        };
        let m = PairMetrics::judged(&est, &gt, 0.5, &outdoor);
        assert!(m.success);
        assert_eq!(m.criterion, SuccessCriterion::KITTI);
        assert!(!m.also.unwrap().success);
        assert!(!PairMetrics::new(&est, &gt, 0.5).success);
        assert_eq!(SuccessCriterion::KITTI.label(), "RRE ≤ 5°, RTE ≤ 2 m");
        let json = serde_json::to_value(m).unwrap();
        assert_eq!(json["criterion"]["max_rte_m"], serde_json::json!(2.0));
        // a result written before the criterion was named reads as 3DMatch's
        let old: PairMetrics = serde_json::from_str(
            r#"{"rre_deg": 1.0, "rte_m": 0.1, "inlier_ratio": 0.2, "success": true}"#,
        )
        .unwrap();
        assert_eq!(old.criterion, SuccessCriterion::THREEDMATCH);
    }

    #[test]
    fn summary_by_hand() {
        let p = |rre: f64, rte: f64, ir: f64| PairMetrics {
            rre_deg: rre,
            rte_m: rte,
            inlier_ratio: ir,
            success: rre <= 15.0 && rte <= 0.3,
            criterion: SuccessCriterion::THREEDMATCH,
            also: None,
        };
        let pairs = [
            p(1.0, 0.02, 0.5),
            p(7.0, 0.08, 0.3),
            p(20.0, 0.2, 0.1),
            p(90.0, 1.0, 0.0),
        ];
        let s = Summary::from_pairs(&pairs);
        assert_eq!(s.n, 4);
        assert_eq!(s.recall, 0.5);
        assert_eq!((s.rot_acc_5, s.rot_acc_10, s.rot_acc_45), (0.25, 0.5, 0.75));
        assert_eq!(
            (s.trans_acc_5cm, s.trans_acc_10cm, s.trans_acc_25cm),
            (0.25, 0.5, 0.75)
        );
        assert!((s.rre_mean - 29.5).abs() < 1e-12);
        assert!((s.rre_median - 13.5).abs() < 1e-12);
        assert!((s.rte_mean - 0.325).abs() < 1e-12);
        assert!((s.rte_median - 0.14).abs() < 1e-12);
        assert!((s.ir_mean - 0.225).abs() < 1e-12);
        let json = serde_json::to_value(&s).unwrap();
        assert_eq!(json["recall"], 0.5);
        let empty = Summary::from_pairs(&[]);
        assert_eq!(empty.n, 0);
        assert_eq!(empty.recall, 0.0);
        assert!(empty.rre_mean.is_nan());
        // a pair that errored (infinite errors) fails the fractions, not the means
        let ok = |rre: f64, rte: f64| PairMetrics {
            rre_deg: rre,
            rte_m: rte,
            inlier_ratio: 0.0,
            success: rre.is_finite(),
            criterion: Default::default(),
            also: None,
        };
        let s =
            Summary::from_pairs(&[ok(2.0, 0.1), ok(4.0, 0.3), ok(f64::INFINITY, f64::INFINITY)]);
        assert_eq!((s.rre_mean, s.rre_median), (3.0, 3.0));
        assert!((s.rte_mean - 0.2).abs() < 1e-12 && (s.rte_median - 0.2).abs() < 1e-12);
        assert!((s.rot_acc_5 - 2.0 / 3.0).abs() < 1e-12 && (s.recall - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn precision_recall_by_hand() {
        let gt = Isometry3::identity();
        let o = Point3::origin();
        let far = Point3::new(1.0f32, 0.0, 0.0);
        // Scores 0.9 (correct), 0.8 (wrong), 0.8 (correct), 0.1 (correct).
        let src = vec![o; 4];
        let tgt = vec![o, far, Point3::new(0.0, 0.04, 0.0), o];
        let pr = precision_recall(&src, &tgt, &[0.9, 0.8, 0.8, 0.1], &gt, 0.05, None).unwrap();
        assert_eq!(pr.len(), 3);
        assert_eq!(
            (pr[0].threshold, pr[0].precision, pr[0].recall),
            (0.9, 1.0, 1.0 / 3.0)
        );
        assert_eq!(
            (pr[1].threshold, pr[1].precision, pr[1].recall),
            (0.8, 2.0 / 3.0, 2.0 / 3.0)
        );
        assert_eq!(
            (pr[2].threshold, pr[2].precision, pr[2].recall),
            (0.1, 0.75, 1.0)
        );
        // Against a larger pool of available correct matches.
        let pr = precision_recall(&src, &tgt, &[0.9, 0.8, 0.8, 0.1], &gt, 0.05, Some(6)).unwrap();
        assert_eq!(pr[2].recall, 0.5);
        assert!(precision_recall(&src, &tgt, &[0.9], &gt, 0.05, None).is_err());
        assert!(precision_recall(&src, &tgt, &[0.9, f32::NAN, 0.1, 0.2], &gt, 0.05, None).is_err());
    }
}
