//! Rigid pose estimation from correspondences: weighted Kabsch, SC2-PCR, RANSAC.

use nalgebra::Isometry3;

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
