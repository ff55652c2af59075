//! The `union` fusion mode in the in-memory tail: the Noisy-AND correspondences and the
//! geometric branch's own (row NN) correspondences from the same inputs, merged
//! ([`crate::fusion::union::merge`]), one estimate, and the result with its provenance.

use super::common::{
    finish, geometry_correspondences, image_correspondences, similarities, EstimateMemo,
    FusionInputs, ImageInputs, Similarities,
};
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::fusion::union::{merge, UnionReport};
use crate::fusion::{Correspondence, FusionMode, FusionParams, Selection};
use crate::pipeline::params::RegisterParams;
use crate::pipeline::result::{RegistrationResult, Timer};
use std::time::Instant;

/// The geometric set of the union: the geometric branch alone with row nearest neighbours
/// (the geometry-alone registration's selection).
pub fn geometry_params(fusion: &FusionParams) -> FusionParams {
    let mut p = *fusion;
    p.mode = FusionMode::GeometryOnly;
    p.selection = Selection::RowNn;
    p
}

/// The Noisy-AND set of the union: the paper's fusion with the run's selection.
pub fn noisy_and_params(fusion: &FusionParams) -> FusionParams {
    let mut p = *fusion;
    p.mode = FusionMode::NoisyAnd;
    p
}

/// The image branch alone with the run's selection (the `image` mode's set).
pub fn image_params(fusion: &FusionParams) -> FusionParams {
    let mut p = *fusion;
    p.mode = FusionMode::ImageOnly;
    p
}

/// The correspondences `fusion` (one of the matrix modes) selects from `inputs`, untimed (the
/// union's members, and studies of other rules).
pub fn mode_correspondences(
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    fusion: &FusionParams,
) -> Result<Vec<Correspondence>> {
    let mut t = Timer::new();
    match fusion.mode {
        FusionMode::GeometryOnly => geometry_correspondences(inputs, sims, fusion, &mut t),
        _ => image_correspondences(inputs, sims, fusion, &mut t),
    }
}

/// The union's two sets (Noisy-AND, geometry) from `inputs` (image descriptors required).
pub(crate) fn member_sets(
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    timer: &mut Timer,
) -> Result<(Vec<Correspondence>, Vec<Correspondence>)> {
    let named = [
        ("noisy-and", noisy_and_params(&params.fusion)),
        ("geometry", geometry_params(&params.fusion)),
    ];
    let [a, g] = branch_sets(inputs, sims, timer, named)?;
    Ok((a, g))
}

/// The sets of several fusions (`named`: the timing row's name and the fusion) from the same
/// `inputs` (image descriptors required). The similarity matrices are formed once (or taken from
/// `sims`), except for a large pair whose image-using sets all stream from the features.
pub(crate) fn branch_sets<const N: usize>(
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    timer: &mut Timer,
    named: [(&str, FusionParams); N],
) -> Result<[Vec<Correspondence>; N]> {
    if inputs.image.is_none() {
        return Err(Error::Missing(
            "fusion: the image branch's descriptors are missing (the union and visibility modes need them)".into(),
        ));
    }
    // Without kept matrices, sets the features can give band by band (the default
    // configuration's Noisy-AND, image and geometry sets) are formed that way at any size: each
    // band of similarity rows as `cosine_similarity` forms it, so the same correspondences,
    // without allocating, zeroing and re-reading two N x M matrices per pair (at 3DMatch sizes
    // that cost more than forming the rows again for each set).
    let streams = matches!(inputs.image, Some(ImageInputs::PerImage(..)))
        && named.iter().all(|(_, f)| {
            f.mode == FusionMode::GeometryOnly || crate::fusion::streams_from_features(f)
        });
    let computed;
    let sims = match sims {
        Some(s) => Some(s),
        None if streams => None,
        None => {
            let t = Instant::now();
            computed = similarities(inputs)?;
            timer.record("similarity", t.elapsed(), false);
            Some(&computed)
        }
    };
    let mut sets = Vec::with_capacity(N);
    for (name, fusion) in &named {
        let t = Instant::now();
        let set = match sims {
            Some(_) => mode_correspondences(inputs, sims, fusion)?,
            None => streamed_set(inputs, fusion)?,
        };
        sets.push(set);
        timer.record(&format!("fusion: {name}"), t.elapsed(), false);
    }
    sets.try_into()
        .map_err(|_| Error::Shape("fusion: a branch set is missing".into()))
}

/// The set `fusion` selects, formed from the features band by band (no N x M matrix): the
/// geometric branch's row NN ([`crate::fusion::streaming`]) or a configuration
/// [`crate::fusion::streams_from_features`] accepts.
fn streamed_set(inputs: &FusionInputs, fusion: &FusionParams) -> Result<Vec<Correspondence>> {
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    if fusion.mode == FusionMode::GeometryOnly {
        return geometry_correspondences(inputs, None, fusion, &mut Timer::new());
    }
    let Some(ImageInputs::PerImage(fs, vs, ft, vt)) = &inputs.image else {
        return Err(Error::Missing(
            "fusion: the image branch's per-point descriptors are missing".into(),
        ));
    };
    let feats = (&src.features, &tgt.features);
    crate::fusion::match_then_fuse_select_features((fs, vs, ft, vt), feats, fusion)?.ok_or_else(
        || {
            Error::Invalid(format!(
                "fusion: {:?} is not formed from features",
                fusion.mode
            ))
        },
    )
}

/// The `union` registration of `pair` from `inputs` (image descriptors present).
pub(crate) fn register(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    mut timer: Timer,
    memo: Option<&EstimateMemo>,
) -> Result<RegistrationResult> {
    let (and, geo) = member_sets(params, inputs, sims, &mut timer)?;
    from_sets(pair, params, inputs, (&and, &geo), timer, memo)
}

/// The `union` registration from its two sets (Noisy-AND, geometry).
pub(crate) fn from_sets(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    (and, geo): (&[Correspondence], &[Correspondence]),
    timer: Timer,
    memo: Option<&EstimateMemo>,
) -> Result<RegistrationResult> {
    let (corr, origin) = merge(and, geo);
    let label = inputs.image_label.clone();
    let src_tgt = (&inputs.source_geo, &inputs.target_geo);
    let mut res = finish(pair, params, timer, src_tgt, corr, label, memo)?;
    let report = UnionReport::new(and.len(), geo.len(), &origin, &res.inliers);
    res.image_branch = res
        .image_branch
        .map(|l| format!("{l}; {})", report.provenance()));
    res.union = Some(report);
    Ok(res)
}
