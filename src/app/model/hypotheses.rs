//! The estimator's ranked hypotheses as the hypothesis browser shows them (plain data,
//! computed by the worker on request).

use nalgebra::Isometry3;

use super::InspectorModel;

/// One row of the list.
#[derive(Clone, Debug, PartialEq)]
pub struct HypothesisRow {
    pub rank: usize,
    pub consensus: usize,
    /// The correspondences it was built from (SC2-PCR: its seed; RANSAC: 3).
    pub sample: Vec<usize>,
    pub rre_deg: Option<f64>,
    pub rte_m: Option<f64>,
    pub winner: bool,
    /// Its pose (target_from_source) before refinement.
    pub pose: Isometry3<f64>,
    /// Indices into `InspectorModel::matches` of its consensus.
    pub inliers: Vec<usize>,
}

/// The list the panel shows (plain data, in the model).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HypothesisList {
    pub estimator: String,
    /// How the estimator ranks them.
    pub rule: String,
    pub threshold_m: f64,
    /// Hypotheses scored in all (`rows` are the best of them).
    pub total: usize,
    pub rows: Vec<HypothesisRow>,
    /// Why there are none (weighted SVD, a fallback, an error).
    pub note: Option<String>,
}

impl HypothesisList {
    pub fn from_ranked(r: &crate::pipeline::hypotheses::RankedHypotheses) -> Self {
        let h = &r.hypotheses;
        HypothesisList {
            estimator: h.estimator.clone(),
            rule: h.rule.clone(),
            threshold_m: h.threshold_m,
            total: h.total,
            rows: h
                .list
                .iter()
                .zip(&r.vs_gt)
                .map(|(x, g)| HypothesisRow {
                    rank: x.rank,
                    consensus: x.consensus,
                    sample: x.sample.clone(),
                    rre_deg: g.map(|g| g.0),
                    rte_m: g.map(|g| g.1),
                    winner: x.winner,
                    pose: x.pose,
                    inliers: x.inliers.clone(),
                })
                .collect(),
            note: None,
        }
    }

    /// No hypotheses, and why.
    pub fn none(note: impl Into<String>) -> Self {
        HypothesisList {
            note: Some(note.into()),
            ..Default::default()
        }
    }

    /// A UI fixture for tests and screenshots of the demo model: poses are the demo's
    /// estimate perturbed, consensus sets made-up subsets of its matches. Labelled as such.
    pub fn fixture(model: &InspectorModel) -> Self {
        let base = model.estimated.unwrap_or(model.initial);
        let n = model.matches.len();
        let rows = (0..8)
            .map(|k| {
                let a = 0.02 * k as f64;
                let pose = base
                    * Isometry3::new(
                        nalgebra::Vector3::new(0.03 * k as f64, 0.0, 0.0),
                        nalgebra::Vector3::new(0.0, 0.0, a),
                    );
                let inliers: Vec<usize> = (0..n).filter(|i| i % (k + 1) == 0).collect();
                HypothesisRow {
                    rank: k + 1,
                    consensus: inliers.len(),
                    sample: vec![k],
                    rre_deg: model
                        .ground_truth
                        .map(|g| crate::metrics::rre_deg(&pose, &g)),
                    rte_m: model.ground_truth.map(|g| crate::metrics::rte_m(&pose, &g)),
                    winner: k == 0,
                    pose,
                    inliers,
                }
            })
            .collect();
        HypothesisList {
            estimator: "fixture (demo data, not an estimator run)".into(),
            rule: "made-up ranks for the UI fixture".into(),
            threshold_m: 0.10,
            total: 8,
            rows,
            note: None,
        }
    }
}
