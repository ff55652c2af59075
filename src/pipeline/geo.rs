//! The geometric branch of one scan: keypoints and features (FPFH computed here, or learned
//! features read from files). The cached FPFH stage is `stages::geo`.

pub use super::inputs::GeoBranch;
pub use super::stages::geo::fpfh_branch;

use super::params::{GeoFeatureSource, RegisterParams};
use super::result::Timer;
use super::stages::geo_spinnet::{self, SpinNetInput};
use super::stages::{geo, Ctx};
use crate::cache::CacheKey;
use crate::dataset::{Scan, ScanPair};
use crate::error::{Error, Result};

/// What the `geo-spinnet` stage reads for `params` (its settings), when SpinNet is the
/// geometric branch.
pub(crate) fn spinnet_input(params: &RegisterParams) -> Option<SpinNetInput<'_>> {
    let RegisterParams {
        voxel,
        geo_features,
        fusion: _,
        estimator: _,
        inlier_threshold: _,
        image: _,
        success: _,
        // each scale hypothesis is a registration at one voxel
        scales: _,
    } = params;
    match geo_features {
        GeoFeatureSource::Spinnet {
            protocol,
            model,
            keypoints,
        } => Some(SpinNetInput {
            protocol: *protocol,
            model,
            keypoints: *keypoints,
            voxel: *voxel,
        }),
        _ => None,
    }
}

/// One scan's geometric branch through its cached stage (`geo-fpfh` or `geo-spinnet`), with
/// the stage's key; `side` is "source" or "target". Features read from files have no stage.
pub(crate) fn cached_branch(
    ctx: &mut Ctx,
    side: &str,
    scan: &Scan,
    params: &RegisterParams,
) -> Result<(GeoBranch, CacheKey)> {
    if let Some(input) = spinnet_input(params) {
        return geo_spinnet::run(ctx, &format!("spinnet {side}"), scan, &input);
    }
    match &params.geo_features {
        GeoFeatureSource::Fpfh => {
            geo::run(ctx, &format!("fpfh {side}"), scan, geo::settings(params))
        }
        other => Err(Error::Invalid(format!(
            "geometric features `{}` have no cached stage; the image branch runs with FPFH or \
             SpinNet",
            other.name()
        ))),
    }
}

pub(crate) fn geo_branches(
    pair: &ScanPair,
    params: &RegisterParams,
    timer: &mut Timer,
) -> Result<(GeoBranch, GeoBranch)> {
    match &params.geo_features {
        GeoFeatureSource::Spinnet { .. } => Err(Error::Invalid(
            "SpinNet runs through its cached stage (pipeline::geo::cached_branch)".into(),
        )),
        GeoFeatureSource::Fpfh => {
            let s = timer.stage_as(geo::NAME, "fpfh source", || {
                fpfh_branch(&pair.source.cloud, params.voxel)
            })?;
            let t = timer.stage_as(geo::NAME, "fpfh target", || {
                fpfh_branch(&pair.target.cloud, params.voxel)
            })?;
            Ok((s, t))
        }
        GeoFeatureSource::Files { source, target } => {
            timer.stage_as(geo::NAME, "load learned features", || {
                let s = crate::features::learned::load_learned_features(source)?;
                let t = crate::features::learned::load_learned_features(target)?;
                Ok((
                    GeoBranch {
                        keypoints: s.points,
                        features: s.feats,
                        label: s.source,
                    },
                    GeoBranch {
                        keypoints: t.points,
                        features: t.feats,
                        label: t.source,
                    },
                ))
            })
        }
        GeoFeatureSource::GeoTransformerPkl { path } => {
            timer.stage_as(geo::NAME, "load geotransformer", || {
                let (r, s) = crate::features::learned::load_geotransformer_pkl(path)?;
                // Reference §5 (3DMatch): GeoTransformer's ref is C-GenReg's source.
                Ok((
                    GeoBranch {
                        keypoints: r.points,
                        features: r.feats,
                        label: r.source,
                    },
                    GeoBranch {
                        keypoints: s.points,
                        features: s.feats,
                        label: s.source,
                    },
                ))
            })
        }
    }
}
