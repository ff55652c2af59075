//! The in-memory tail of every registration: similarity, calibration, Match-then-Fuse,
//! selection, estimation and evaluation. Cheap next to the cached stages, so a change of
//! temperature, fusion mode, selection or estimator re-runs only [`fuse_and_finish`], which
//! hands each fusion mode to its arbiter: `union` (both branches' correspondences merged),
//! `visibility` (the candidate poses scored against the depth views), the matrix modes and
//! geometry alone (`common`, which the others build on).

mod common;
pub mod union;
pub mod visibility;

pub use common::{
    endpoints, key, similarities, EstimateMemo, FusionInputs, ImageInputs, Similarities, NAME,
    STAGE, STREAM_ENTRIES, VERSION,
};

use crate::dataset::ScanPair;
use crate::error::Result;
use crate::fusion::FusionMode;
use crate::pipeline::params::RegisterParams;
use crate::pipeline::result::{RegistrationResult, Timer};

/// Similarity, calibration, fusion, selection and estimation from [`FusionInputs`]: the tail
/// of the image branch (image descriptors present) and of the geometric-only registration
/// (image None: geometry-only fusion, streaming row-NN when the calibration allows it).
/// `sims`: the similarity matrices computed before ([`similarities`]; the GUI keeps them),
/// None computes them here; the result is the same. `res.image` is left None: the caller
/// attaches the views. The estimate is taken from `memo` when the correspondences and the
/// estimator are those of its last call (the result is the same; the estimate's timing row
/// then says "cached"). [`crate::pipeline::Registration`] is the way in.
pub(crate) fn fuse_and_finish(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    memo: Option<&EstimateMemo>,
) -> Result<RegistrationResult> {
    let timer = Timer::new();
    match (&inputs.image, params.fusion.mode) {
        (Some(_), FusionMode::Union) => union::register(pair, params, inputs, sims, timer, memo),
        (Some(_), FusionMode::Visibility) => {
            visibility::register(pair, params, inputs, sims, timer, memo)
        }
        _ => common::fuse_matrix_mode(pair, params, inputs, sims, timer, memo),
    }
}
