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
    /// The outdoor protocol plus scale hypotheses (voxels 0.3, 0.6 and 1.2 m, the pose most
    /// consistent with both scans' range views kept): for LiDAR data whose scale no published
    /// configuration fixes (docs/outdoor.md, "Scale hypotheses").
    OutdoorSearch,
}

impl Preset {
    pub const ALL: [Preset; 3] = [Preset::Indoor, Preset::Outdoor, Preset::OutdoorSearch];

    pub fn name(self) -> &'static str {
        match self {
            Preset::Indoor => "indoor",
            Preset::Outdoor => "outdoor",
            Preset::OutdoorSearch => "outdoor-search",
        }
    }

    pub fn label(self) -> &'static str {
        match self {
            Preset::Indoor => "indoor (3DMatch protocol)",
            Preset::Outdoor => "outdoor (KITTI protocol)",
            Preset::OutdoorSearch => "outdoor, scale search (KITTI protocol at 3 voxels)",
        }
    }

    /// The keypoint voxel (m).
    pub fn voxel(self) -> f64 {
        match self {
            Preset::Indoor => 0.05,
            Preset::Outdoor | Preset::OutdoorSearch => 0.3,
        }
    }

    /// Scale hypotheses: the registration at the voxels v, 2 v, ... (`scales` octaves), the
    /// most visibility-consistent pose kept; 1 = the voxel alone.
    pub fn scales(self) -> u32 {
        match self {
            Preset::Indoor | Preset::Outdoor => 1,
            Preset::OutdoorSearch => 3,
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
            Preset::Outdoor | Preset::OutdoorSearch => SuccessCriteria {
                primary: SuccessCriterion::KITTI,
                also: Some(SuccessCriterion::SC2PCR_KITTI),
            },
        }
    }
}
