//! The published protocols a data set (or a run) can start from: the keypoint voxel and the
//! success criterion. What a preset does to the pipeline's parameters (every distance following
//! the voxel) is `pipeline::params` (`Preset::apply`, `Preset::of`).

use serde::{Deserialize, Serialize};

use crate::metrics::{SuccessCriteria, SuccessCriterion};

/// The published protocols a run can start from: the keypoint voxel (every following distance
/// with it, [`crate::estimate::scale`]) and the success criterion.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// The 3DMatch protocol (SC2-PCR's `config_3DMatch.json`): voxel 0.05 m, thresholds
    /// 0.10 m; success RRE ≤ 15°, RTE ≤ 0.30 m.
    #[default]
    Indoor,
    /// The KITTI protocol (SC2-PCR's `config_KITTI.json`): voxel 0.3 m, thresholds 0.6 m,
    /// 8000 correspondences; success RRE ≤ 5°, RTE ≤ 2 m (KITTI's benchmark), SC2-PCR's
    /// 5° / 0.6 m beside it.
    Outdoor,
}

impl Preset {
    pub const ALL: [Preset; 2] = [Preset::Indoor, Preset::Outdoor];

    pub fn name(self) -> &'static str {
        match self {
            Preset::Indoor => "indoor",
            Preset::Outdoor => "outdoor",
        }
    }

    pub fn label(self) -> &'static str {
        match self {
            Preset::Indoor => "indoor (3DMatch protocol)",
            Preset::Outdoor => "outdoor (KITTI protocol)",
        }
    }

    /// The keypoint voxel (m).
    pub fn voxel(self) -> f64 {
        match self {
            Preset::Indoor => 0.05,
            Preset::Outdoor => 0.3,
        }
    }

    /// SC2-PCR's `max_points` (`num_node` of the KITTI configuration; the 3DMatch one uses
    /// MyMatcher's 8000).
    pub fn max_points(self) -> usize {
        8000
    }

    pub fn success(self) -> SuccessCriteria {
        match self {
            Preset::Indoor => SuccessCriteria {
                primary: SuccessCriterion::THREEDMATCH,
                also: None,
            },
            Preset::Outdoor => SuccessCriteria {
                primary: SuccessCriterion::KITTI,
                also: Some(SuccessCriterion::SC2PCR_KITTI),
            },
        }
    }
}
