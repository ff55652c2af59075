//! What the arbitration modes report, as data beside the result that carries them: the
//! `visibility` fusion's candidate poses and scores ([`VisibilityReport`]), the scale search's
//! hypotheses ([`ScaleReport`]); the `union` fusion's report is `fusion::union::UnionReport`.
//! The modes themselves are `tail/visibility.rs`, `scales.rs` and `tail/union.rs`.

use crate::dataset::ViewOrigin;
use serde::{Deserialize, Serialize};

/// A pose the visibility mode chooses among.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Candidate {
    Union,
    Geometry,
    NoisyAnd,
    Image,
}

impl Candidate {
    /// The tie order.
    pub const ALL: [Candidate; 4] = [
        Candidate::Union,
        Candidate::Geometry,
        Candidate::NoisyAnd,
        Candidate::Image,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Candidate::Union => "union",
            Candidate::Geometry => "geometry",
            Candidate::NoisyAnd => "Noisy-AND",
            Candidate::Image => "image",
        }
    }
}

/// One candidate pose's visibility (source keypoints in the target's views plus target
/// keypoints in the source's views).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CandidateScore {
    pub pose: Candidate,
    pub consistent: usize,
    pub conflict: usize,
    /// V = consistent - conflict (shown; not what decides).
    pub score: i64,
    /// F: the 95 % lower bound of consistent / (consistent + conflict), what decides (0 in a
    /// report written before the share decided).
    #[serde(default)]
    pub share: f64,
    /// The estimator's inliers of this pose on its own correspondences.
    pub inliers: usize,
}

/// What the visibility mode compared and kept: the result's provenance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VisibilityReport {
    pub chosen: Candidate,
    /// Every candidate, in the tie order (none in a report of a version that kept the union's
    /// pose with virtual views without comparing).
    pub candidates: Vec<CandidateScore>,
    /// The depth views each side was checked against.
    pub source_views: usize,
    pub target_views: usize,
    /// Where the views' cameras stand (the weaker side's): the sensor's frames, or a virtual
    /// trajectory around a cloud. Results written before this field existed had sensor views.
    #[serde(default = "sensor_views")]
    pub views: ViewOrigin,
    /// The candidates whose pose could not be estimated (too few correspondences, a degenerate
    /// set), with the reason: left out of the comparison, never fatal while another pose is.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub skipped: Vec<SkippedCandidate>,
}

/// A candidate the visibility mode could not estimate, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkippedCandidate {
    pub pose: Candidate,
    pub reason: String,
}

impl VisibilityReport {
    /// "fusion: visibility (kept the image pose; F = 95 % lower bound of the share of seen
    /// keypoints consistent with 50 + 50 sensor depth views: union 0.409, geometry 0.408,
    /// Noisy-AND 0.437, image 0.815)".
    pub fn provenance(&self) -> String {
        if self.candidates.is_empty() {
            return format!(
                "fusion: visibility ({}: kept the {} pose; poses not compared)",
                self.views.label(),
                self.chosen.label()
            );
        }
        let f: Vec<String> = self
            .candidates
            .iter()
            .map(|c| format!("{} {:.3}", c.pose.label(), c.share))
            .collect();
        let skipped: String = self
            .skipped
            .iter()
            .map(|c| format!("; {} pose not estimated: {}", c.pose.label(), c.reason))
            .collect();
        format!(
            "fusion: visibility (kept the {} pose; F = 95 % lower bound of the share of seen \
             keypoints consistent with {} + {} depth views ({}): {}{skipped})",
            self.chosen.label(),
            self.source_views,
            self.target_views,
            self.views.label(),
            f.join(", ")
        )
    }
}

fn sensor_views() -> ViewOrigin {
    ViewOrigin::Sensor
}

/// One hypothesis's voxel and visibility.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleHypothesis {
    pub voxel: f64,
    pub consistent: usize,
    pub conflict: usize,
    /// consistent - conflict.
    pub score: i64,
    /// The estimator's inliers at this hypothesis's own threshold.
    pub inliers: usize,
}

/// What the scale search compared and kept: the result's provenance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleReport {
    pub chosen_voxel: f64,
    /// Every hypothesis, finest first.
    pub hypotheses: Vec<ScaleHypothesis>,
    /// The points scored (the finest hypothesis's keypoints) and the distance (its inlier
    /// threshold, m).
    pub scored_voxel: f64,
    pub theta: f64,
    pub source_views: usize,
    pub target_views: usize,
}

impl ScaleReport {
    /// "scales: kept voxel 1.2 m of 0.3, 0.6, 1.2 m (V = consistent - conflicting keypoints
    /// of voxel 0.3 m within 0.6 m, in 4 + 4 depth views: 0.3 m -1210, 0.6 m -800, 1.2 m 2310)".
    pub fn provenance(&self) -> String {
        let voxels: Vec<String> = self
            .hypotheses
            .iter()
            .map(|h| format!("{}", h.voxel))
            .collect();
        let scores: Vec<String> = self
            .hypotheses
            .iter()
            .map(|h| format!("{} m {}", h.voxel, h.score))
            .collect();
        format!(
            "scales: kept voxel {} m of {} m (V = consistent - conflicting keypoints of voxel \
             {} m within {} m, in {} + {} depth views: {})",
            self.chosen_voxel,
            voxels.join(", "),
            self.scored_voxel,
            self.theta,
            self.source_views,
            self.target_views,
            scores.join(", ")
        )
    }
}
