//! Parameters of a registration run. Every field is serialisable so a run can be cached,
//! reproduced from its JSON, and shown in the GUI and the CLI output.

use crate::estimate::EstimatorKind;
use crate::fusion::FusionParams;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where the geometric branch's features come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum GeoFeatureSource {
    /// FPFH computed here on the voxel-downsampled clouds.
    Fpfh,
    /// Precomputed learned features (points + feats), one file per scan (.npz / .pkl).
    Files { source: PathBuf, target: PathBuf },
    /// The authors' GeoTransformer pair file (reference §5): GeoTransformer's `ref` is the
    /// C-GenReg source for 3DMatch.
    GeoTransformerPkl { path: PathBuf },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegisterParams {
    /// Voxel size (m) of the geometric keypoints; FPFH radii follow it (normals 2v, features 5v).
    pub voxel: f64,
    pub geo_features: GeoFeatureSource,
    pub fusion: FusionParams,
    pub estimator: EstimatorKind,
    /// Threshold (m) for the inlier ratio of the selected correspondences under ground truth.
    pub inlier_threshold: f64,
}

impl Default for RegisterParams {
    fn default() -> Self {
        RegisterParams {
            voxel: 0.05,
            geo_features: GeoFeatureSource::Fpfh,
            fusion: FusionParams::default(),
            estimator: EstimatorKind::default(),
            inlier_threshold: 0.10,
        }
    }
}
