//! One registration: geometric branch (and, when configured, the image branch), Match-then-Fuse,
//! pose estimation and evaluation against ground truth. The entry points; the stages are in
//! `stages/`, the shared in-memory tail in `fuse`.

use super::cache::Cache;
use super::fuse::{fuse_and_finish, FusionInputs};
use super::geo::{cached_branch, geo_branches};
use super::memo::Memo;
use super::params::{GeoFeatureSource, RegisterParams};
use super::result::RegistrationResult;
use super::stages::Ctx;
use crate::dataset::ScanPair;
use crate::error::{Error, Result};

/// Register `pair.source` onto `pair.target`: the geometric branch, plus the image branch
/// when `params.image` is set (everything computed in memory, no cache).
pub fn register_pair(pair: &ScanPair, params: &RegisterParams) -> Result<RegistrationResult> {
    register_pair_cached(pair, params, None)
}

/// [`register_pair`] with the image branch's stages read from / written to `cache` (models
/// and file hashes kept for this call only; see [`register_pair_cached_keep`]).
pub fn register_pair_cached(
    pair: &ScanPair,
    params: &RegisterParams,
    cache: Option<&Cache>,
) -> Result<RegistrationResult> {
    register_pair_cached_keep(pair, params, cache, &Memo::default()).map(|(r, _)| r)
}

/// [`register_pair_cached`] that also returns the [`FusionInputs`] the result was computed
/// from (what the correspondence export and the posterior inspector recompute from). `memo`
/// is the caller's: a caller of many pairs keeps one, so each model loads once.
pub fn register_pair_cached_keep(
    pair: &ScanPair,
    params: &RegisterParams,
    cache: Option<&Cache>,
    memo: &Memo,
) -> Result<(RegistrationResult, FusionInputs)> {
    match &params.image {
        Some(ib) => {
            super::image_branch::register_with_image_keep(pair, params, ib, cache, memo, true)
        }
        None => register_geometry(pair, params, cache, memo),
    }
}

/// The geometric branch alone: keypoints and features (FPFH through the cached `geo-fpfh`
/// stage, as with the image branch), then the shared tail ([`fuse_and_finish`] with no image
/// descriptors).
fn register_geometry(
    pair: &ScanPair,
    params: &RegisterParams,
    cache: Option<&Cache>,
    memo: &Memo,
) -> Result<(RegistrationResult, FusionInputs)> {
    let mut ctx = Ctx::new(cache, memo);
    // FPFH and SpinNet through their cached stages; features read from files have none
    let (src, tgt) = match params.geo_features {
        GeoFeatureSource::Fpfh | GeoFeatureSource::Spinnet { .. } => (
            cached_branch(&mut ctx, "source", &pair.source, params)?.0,
            cached_branch(&mut ctx, "target", &pair.target, params)?.0,
        ),
        _ => geo_branches(pair, params, &mut ctx.timer)?,
    };
    if src.features.dim != tgt.features.dim {
        return Err(Error::Invalid(format!(
            "source features are {}-D but target features are {}-D",
            src.features.dim, tgt.features.dim
        )));
    }
    let inputs = FusionInputs {
        source_geo: src,
        target_geo: tgt,
        image: None,
        image_label: None,
    };
    let mut res = fuse_and_finish(pair, params, &inputs, None)?;
    let Ctx {
        timer, warnings, ..
    } = ctx;
    let mut timings = timer.timings;
    timings.append(&mut res.timings);
    res.timings = timings;
    res.total_ms = timer.t0.elapsed().as_secs_f64() * 1e3;
    res.warnings.extend(warnings);
    Ok((res, inputs))
}
