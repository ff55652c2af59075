//! A guard against ground truth in the wrong convention: does the given `target_from_source`
//! explain the data, or does its inverse (`source_from_target`, the other common convention)
//! explain it clearly better?
//!
//! Evidence, each under the ground truth `G` and under its inverse `G⁻¹`:
//! - **overlap**: the fraction of source keypoints (at most [`MAX_CHECKED`], evenly strided)
//!   whose nearest target keypoint lies within `threshold_m` after the transform;
//! - **correspondence inliers** (informative only): the fraction of the selected
//!   correspondences with `‖T src − tgt‖ <= threshold_m`.
//!
//! **Rule**: the inverse explains the data clearly better when its overlap is at least
//! twice the ground truth's **and** exceeds it by at least [`MIN_MARGIN`] (10 points of
//! fraction). When `G` is close to its own inverse (small motions) both overlaps are alike
//! and nothing is said; when neither explains the data (no overlap at all) nothing is said.

use crate::geometry::knn::KdIndex;
use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

/// Source keypoints checked at most (strided subsample: bounded cost on every re-fusion).
pub const MAX_CHECKED: usize = 4000;
/// The inverse's overlap must exceed the ground truth's by at least this fraction.
pub const MIN_MARGIN: f64 = 0.10;
/// ... and be at least this many times the ground truth's.
pub const MIN_RATIO: f64 = 2.0;

/// What [`check_gt_convention`] found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConventionCheck {
    /// Distance (m) under which a transformed source point counts as explained.
    pub threshold_m: f64,
    /// Source keypoints checked.
    pub points_checked: usize,
    /// Overlap fraction under the ground truth and under its inverse.
    pub overlap_gt: f64,
    pub overlap_inverse: f64,
    /// Inlier fraction of the selected correspondences under each (None: no correspondences).
    pub corr_inliers_gt: Option<f64>,
    pub corr_inliers_inverse: Option<f64>,
    /// The rule of the module docs fired.
    pub inverse_explains_better: bool,
    /// The warning to show next to the metrics when it fired.
    pub warning: Option<String>,
}

fn overlap(
    src: &[Point3<f32>],
    stride: usize,
    index: &KdIndex,
    t: &Isometry3<f64>,
    thr: f64,
) -> (usize, usize) {
    let tf = t.cast::<f32>();
    let mut hit = 0;
    let mut n = 0;
    for p in src.iter().step_by(stride) {
        n += 1;
        if index
            .nearest(&(tf * p))
            .is_some_and(|(_, d)| (d as f64) <= thr)
        {
            hit += 1;
        }
    }
    (hit, n)
}

fn corr_fraction(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    t: &Isometry3<f64>,
    thr: f64,
) -> Option<f64> {
    if src.is_empty() || src.len() != tgt.len() {
        return None;
    }
    let ok = src
        .iter()
        .zip(tgt)
        .filter(|(p, q)| (t * p.cast::<f64>() - q.cast::<f64>()).norm() <= thr)
        .count();
    Some(ok as f64 / src.len() as f64)
}

/// Compares how well `gt` (`target_from_source`) and its inverse explain the clouds
/// (`source_keypoints` onto `target_keypoints`) and the correspondences `corr_src[i] ↔
/// corr_tgt[i]`, under `threshold_m` (the module docs state the rule). None when a cloud is
/// empty.
pub fn check_gt_convention(
    source_keypoints: &[Point3<f32>],
    target_keypoints: &[Point3<f32>],
    corr_src: &[Point3<f32>],
    corr_tgt: &[Point3<f32>],
    gt: &Isometry3<f64>,
    threshold_m: f64,
) -> Option<ConventionCheck> {
    if source_keypoints.is_empty() || target_keypoints.is_empty() {
        return None;
    }
    let index = KdIndex::new(target_keypoints);
    let stride = source_keypoints.len().div_ceil(MAX_CHECKED).max(1);
    let inv = gt.inverse();
    let (hg, n) = overlap(source_keypoints, stride, &index, gt, threshold_m);
    let (hi, _) = overlap(source_keypoints, stride, &index, &inv, threshold_m);
    let (og, oi) = (hg as f64 / n as f64, hi as f64 / n as f64);
    let fires = oi >= MIN_RATIO * og && oi - og >= MIN_MARGIN;
    let (cg, ci) = (
        corr_fraction(corr_src, corr_tgt, gt, threshold_m),
        corr_fraction(corr_src, corr_tgt, &inv, threshold_m),
    );
    let warning = fires.then(|| {
        format!(
            "ground truth convention? its inverse explains the data better: {:.0} % of source \
             keypoints land within {:.0} cm of the target under the inverse, {:.0} % under the \
             given target_from_source{}",
            100.0 * oi,
            100.0 * threshold_m,
            100.0 * og,
            match (cg, ci) {
                (Some(g), Some(i)) => format!(
                    " (correspondence inliers {:.0} % vs {:.0} %)",
                    100.0 * i,
                    100.0 * g
                ),
                _ => String::new(),
            }
        )
    });
    Some(ConventionCheck {
        threshold_m,
        points_checked: n,
        overlap_gt: og,
        overlap_inverse: oi,
        corr_inliers_gt: cg,
        corr_inliers_inverse: ci,
        inverse_explains_better: fires,
        warning,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// A synthetic room-like cloud seen from two poses: the right GT is quiet, its inverse
    /// (given by mistake) fires; a near-identity GT never fires.
    #[test]
    fn fires_for_the_inverse_only() {
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (u, v) = (i as f32 * 0.05, j as f32 * 0.05);
                pts.push(Point3::new(u, v, 0.0));
                pts.push(Point3::new(u, 0.0, v));
                pts.push(Point3::new(0.0, u, v));
            }
        }
        let gt = Isometry3::from_parts(
            Translation3::new(0.4, -0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.6),
        );
        // target = gt * source
        let tgt: Vec<Point3<f32>> = pts.iter().map(|p| gt.cast::<f32>() * p).collect();
        let ok = check_gt_convention(&pts, &tgt, &pts, &tgt, &gt, 0.1).unwrap();
        assert!(!ok.inverse_explains_better, "{ok:?}");
        assert!(
            ok.overlap_gt > 0.99 && ok.corr_inliers_gt == Some(1.0),
            "{ok:?}"
        );
        let bad = check_gt_convention(&pts, &tgt, &pts, &tgt, &gt.inverse(), 0.1).unwrap();
        assert!(bad.inverse_explains_better, "{bad:?}");
        assert!(bad.warning.as_deref().unwrap().contains("inverse"));
        let tiny = Isometry3::translation(0.01, 0.0, 0.0);
        let same: Vec<Point3<f32>> = pts.iter().map(|p| tiny.cast::<f32>() * p).collect();
        let t = check_gt_convention(&pts, &same, &[], &[], &tiny.inverse(), 0.1).unwrap();
        assert!(!t.inverse_explains_better, "{t:?}");
        assert!(check_gt_convention(&[], &tgt, &[], &[], &gt, 0.1).is_none());
    }
}
