//! A pair browser row's outcome, and what the official 3DMatch recall needs of a row.

use nalgebra::Isometry3;

use super::PairEntry;

/// The ground truth and gt.info information matrix of a pair the official 3DMatch recall
/// counts, as the manifest gives them (what `bench` computes the RMSE from).
#[derive(Clone, Debug, PartialEq)]
pub struct RmseReference {
    pub gt_target_from_source: Isometry3<f64>,
    pub information: nalgebra::Matrix6<f64>,
}

/// What the pair browser's status column and its filter say of a row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PairOutcome {
    Pending,
    Running,
    /// Registered and within the recall thresholds.
    Success,
    /// Registered, outside the thresholds.
    Failure,
    /// Registered without ground truth.
    Done,
    /// Not registered (an error).
    Error,
}

impl PairOutcome {
    pub fn label(self) -> &'static str {
        match self {
            Self::Pending => "pending",
            Self::Running => "running",
            Self::Success => "success",
            Self::Failure => "failure",
            Self::Done => "done (no GT)",
            Self::Error => "error",
        }
    }
}

impl PairEntry {
    /// A row not run yet of a manifest's pair: its split, scene and, when the official
    /// 3DMatch recall counts it, the reference its RMSE is computed against (as `bench` does).
    pub fn of_spec(spec: &crate::dataset::manifest::PairSpec) -> Self {
        let rmse_ref = match (&spec.gt_info, &spec.gt_target_from_source) {
            (Some(info), Some(gt))
                if crate::metrics::field::rmse_counts(info.target, info.source) =>
            {
                Some(Box::new(RmseReference {
                    gt_target_from_source: *gt,
                    information: info.information,
                }))
            }
            _ => None,
        };
        Self {
            scene: spec.scene.clone(),
            rmse_ref,
            ..Self::pending(spec.id.clone(), spec.split.clone())
        }
    }
}
