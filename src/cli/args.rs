//! Pipeline options shared by `register`, `bench` and the GUI's command line.

use crate::estimate::ransac::RansacParams;
use crate::estimate::sc2pcr::Sc2PcrParams;
use crate::estimate::EstimatorKind;
use crate::fusion::calibrate::Calibration;
use crate::fusion::fuse::FusionMode;
use crate::fusion::select::Selection;
use crate::pipeline::params::{GeoFeatureSource, RegisterParams};
use clap::{Args, ValueEnum};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum CalibrationArg {
    /// The paper's row softmax over target points (eq. 5).
    Row,
    /// The reference code's dual softmax sqrt(Pr*Pc + 1e-9).
    Dual,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FusionArg {
    NoisyAnd,
    NoisyOr,
    Concat,
    Image,
    Geometry,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum SelectionArg {
    /// Mutual nearest neighbours of the fused posterior (paper).
    Mutual,
    /// Global top-k entries (reference code, k = 8000).
    Topk,
    /// Each source point's best target, no mutual check (SC2-PCR's FPFH protocol).
    Nn,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum EstimatorArg {
    Sc2pcr,
    Ransac,
    Svd,
}

#[derive(Args, Debug, Clone)]
pub struct PipelineArgs {
    /// Keypoint voxel size in metres (FPFH radii: normals 2v, features 5v).
    #[arg(long, default_value_t = 0.05)]
    pub voxel: f64,
    /// Learned features for the source scan (.npz with points/feats, or .pkl); needs --learned-target.
    #[arg(long, requires = "learned_target")]
    pub learned_source: Option<PathBuf>,
    #[arg(long, requires = "learned_source")]
    pub learned_target: Option<PathBuf>,
    /// The authors' GeoTransformer pair feature file (.pkl, reference §5).
    #[arg(long, conflicts_with = "learned_source")]
    pub geotransformer_pkl: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = CalibrationArg::Row)]
    pub calibration: CalibrationArg,
    /// Softmax temperature of the image branch.
    #[arg(long, default_value_t = 0.1)]
    pub tau_img: f32,
    /// Softmax temperature of the geometric branch.
    #[arg(long, default_value_t = 0.1)]
    pub tau_geo: f32,
    #[arg(long, value_enum, default_value_t = FusionArg::NoisyAnd)]
    pub fusion: FusionArg,
    /// Noisy-AND prior; default 1/(N*M).
    #[arg(long)]
    pub prior: Option<f64>,
    /// Correspondence selection. Default: `nn` when only the geometric branch runs (the
    /// SC2-PCR FPFH protocol), `mutual` when branches are fused (the paper).
    #[arg(long, value_enum)]
    pub selection: Option<SelectionArg>,
    /// k of --selection topk.
    #[arg(long, default_value_t = 8000)]
    pub topk: usize,
    #[arg(long, value_enum, default_value_t = EstimatorArg::Sc2pcr)]
    pub estimator: EstimatorArg,
    /// Reproduce the authors' code: dual softmax, global top-8000, f32 Noisy-AND as written.
    #[arg(long)]
    pub reference: bool,
}

impl PipelineArgs {
    pub fn to_params(&self, image_branch: bool) -> RegisterParams {
        let mut p = RegisterParams {
            voxel: self.voxel,
            ..Default::default()
        };
        p.geo_features = match (
            &self.learned_source,
            &self.learned_target,
            &self.geotransformer_pkl,
        ) {
            (Some(s), Some(t), _) => GeoFeatureSource::Files {
                source: s.clone(),
                target: t.clone(),
            },
            (_, _, Some(pkl)) => GeoFeatureSource::GeoTransformerPkl { path: pkl.clone() },
            _ => GeoFeatureSource::Fpfh,
        };
        let (cal, sel) = if self.reference {
            (CalibrationArg::Dual, Selection::TopK(8000))
        } else {
            (
                self.calibration,
                match self.selection.unwrap_or(if image_branch {
                    SelectionArg::Mutual
                } else {
                    SelectionArg::Nn
                }) {
                    SelectionArg::Mutual => Selection::MutualNn,
                    SelectionArg::Topk => Selection::TopK(self.topk),
                    SelectionArg::Nn => Selection::RowNn,
                },
            )
        };
        let calib = |tau: f32| match cal {
            CalibrationArg::Row => Calibration::RowSoftmax { tau },
            CalibrationArg::Dual => Calibration::DualSoftmax { tau },
        };
        p.fusion.calibration_img = calib(self.tau_img);
        p.fusion.calibration_geo = calib(self.tau_geo);
        p.fusion.mode = match self.fusion {
            FusionArg::NoisyAnd => FusionMode::NoisyAnd,
            FusionArg::NoisyOr => FusionMode::NoisyOr,
            FusionArg::Concat => FusionMode::Concat,
            FusionArg::Image => FusionMode::ImageOnly,
            FusionArg::Geometry => FusionMode::GeometryOnly,
        };
        p.fusion.prior = self.prior;
        p.fusion.selection = sel;
        p.fusion.exact_reference = self.reference;
        p.estimator = match self.estimator {
            EstimatorArg::Sc2pcr => EstimatorKind::Sc2Pcr(Sc2PcrParams::default()),
            EstimatorArg::Ransac => EstimatorKind::Ransac(RansacParams::default()),
            EstimatorArg::Svd => EstimatorKind::WeightedSvd,
        };
        p
    }
}
