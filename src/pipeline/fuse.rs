//! The in-memory tail of every registration: similarity, calibration, Match-then-Fuse,
//! selection, estimation and evaluation. Cheap next to the cached stages, so a change of
//! temperature, fusion mode, selection or estimator re-runs only [`fuse_and_finish`].

use super::geo::GeoBranch;
use super::params::RegisterParams;
use super::result::{matrix_rows, RegistrationResult, Timer};
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::estimate::{estimate_pose, Estimate};
use crate::features::Features;
use crate::fusion::matrix::DenseMatrix;
use crate::fusion::{cosine_similarity, match_then_fuse_select, Calibration, Correspondence};
use crate::fusion::{FusionMode, Selection};
use crate::metrics::PairMetrics;
use crate::vfm::pair_similarity::PairPointDescriptors;
use nalgebra::Point3;
use std::time::{Duration, Instant};

/// The in-memory tail's name in key comparisons (not cached: no folder of that name).
pub const STAGE: &str = "fusion";
pub const VERSION: u32 = 1;

/// The tail's key: the keys of its inputs (both scans' geometric branch, then the image
/// descriptors' stage) and every parameter [`fuse_and_finish`] reads: the fusion (similarity,
/// calibrations, mode, selection), the estimator and the inlier threshold.
pub fn key(params: &RegisterParams, inputs: &[&str]) -> Result<super::cache::CacheKey> {
    super::cache::CacheKey::new(
        STAGE,
        VERSION,
        inputs,
        &serde_json::json!({
            "fusion": params.fusion,
            "estimator": params.estimator,
            "inlier_threshold": params.inlier_threshold,
        }),
    )
}

/// Inputs of the in-memory stages (similarity onward): with them, a change of temperature,
/// fusion mode, selection or estimator re-runs only [`fuse_and_finish`] (the GUI keeps them).
#[derive(Clone, Debug)]
pub struct FusionInputs {
    pub source_geo: GeoBranch,
    pub target_geo: GeoBranch,
    /// The image branch's per-point descriptors; None: geometry only.
    pub image: Option<ImageInputs>,
    /// Label of the image branch, as in `RegistrationResult::image_branch` (fusion mode aside).
    pub image_label: Option<String>,
}

/// Per-point image descriptors, as the image similarity needs them.
#[derive(Clone, Debug)]
pub enum ImageInputs {
    /// One unit descriptor per keypoint and its validity: (source, valid, target, valid).
    PerImage(Features, Vec<bool>, Features, Vec<bool>),
    /// Pair-conditioned descriptors (MASt3R): one per keypoint and partner view.
    PairConditioned(PairPointDescriptors),
}

impl ImageInputs {
    /// Which source / target keypoints have an image descriptor.
    pub fn validity(&self) -> (Vec<bool>, Vec<bool>) {
        match self {
            ImageInputs::PerImage(_, vs, _, vt) => (vs.clone(), vt.clone()),
            ImageInputs::PairConditioned(d) => (
                d.src_view.iter().map(Option::is_some).collect(),
                d.tgt_view.iter().map(Option::is_some).collect(),
            ),
        }
    }

    /// The N x M image similarity with its row / column validity.
    pub fn similarity(&self) -> Result<(DenseMatrix, Vec<bool>, Vec<bool>)> {
        match self {
            ImageInputs::PerImage(fs, vs, ft, vt) => {
                Ok((cosine_similarity(fs, ft)?, vs.clone(), vt.clone()))
            }
            ImageInputs::PairConditioned(d) => d.similarity(),
        }
    }

    /// Row `i` of [`Self::similarity`] (the GUI's posterior inspector), without the matrix.
    pub fn similarity_row(&self, i: usize) -> Vec<f32> {
        match self {
            ImageInputs::PerImage(fs, _, ft, _) => {
                let norm = |v: &[f32]| dot(v, v).sqrt().max(1e-12);
                let a = fs.row(i);
                let na = norm(a);
                (0..ft.len())
                    .map(|j| {
                        let b = ft.row(j);
                        dot(a, b) / (na * norm(b))
                    })
                    .collect()
            }
            ImageInputs::PairConditioned(d) => d.similarity_row(i),
        }
    }
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The similarity matrices of [`FusionInputs`]: they do not depend on temperature, fusion
/// mode, selection or estimator, so the GUI keeps them between re-fusions (2 x N x M f32).
#[derive(Debug)]
pub struct Similarities {
    /// Image similarity with its row / column validity (None: geometry only).
    pub image: Option<(DenseMatrix, Vec<bool>, Vec<bool>)>,
    pub geo: DenseMatrix,
}

/// Both similarity matrices of `inputs`.
pub fn similarities(inputs: &FusionInputs) -> Result<Similarities> {
    let geo = cosine_similarity(&inputs.source_geo.features, &inputs.target_geo.features)?;
    let image = match &inputs.image {
        Some(im) => Some(im.similarity()?),
        None => None,
    };
    Ok(Similarities { image, geo })
}

/// Similarity, calibration, fusion, selection and estimation from [`FusionInputs`]: the tail
/// of the image branch (image descriptors present) and of the geometric-only registration
/// (image None: geometry-only fusion, streaming row-NN when the calibration allows it).
/// `sims`: the similarity matrices computed before ([`similarities`]; the GUI keeps them),
/// None computes them here; the result is the same. `res.image` is left None: the caller
/// attaches the views.
pub fn fuse_and_finish(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
) -> Result<RegistrationResult> {
    let mut timer = Timer::new();
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let corr = match &inputs.image {
        Some(image) => {
            let t = Instant::now();
            let computed;
            let (s_img, v_src, v_tgt, s_geo) = match sims {
                Some(Similarities {
                    image: Some((s, vs, vt)),
                    geo,
                }) => {
                    // kept in memory: shown as a hit, like the stage cache's entries
                    timer.record("similarity", Duration::ZERO, true);
                    (s, vs, vt, geo)
                }
                Some(_) => return Err(mismatch()),
                None => {
                    let (s, vs, vt) = image.similarity()?;
                    let geo = cosine_similarity(&src.features, &tgt.features)?;
                    computed = (s, vs, vt, geo);
                    timer.record("similarity", t.elapsed(), false);
                    (&computed.0, &computed.1, &computed.2, &computed.3)
                }
            };
            let t = Instant::now();
            // Same correspondences as `match_then_fuse`, without its N x M outputs.
            let corr = match_then_fuse_select(
                Some((s_img, Some(v_src), Some(v_tgt))),
                Some(s_geo),
                &params.fusion,
            )?;
            timer.record("fusion", t.elapsed(), false);
            corr
        }
        None => {
            let mut fusion = params.fusion;
            fusion.mode = FusionMode::GeometryOnly;
            let t = Instant::now();
            // Row softmax keeps each row's argmax, so nearest-neighbour selection needs no
            // N x M matrix (same result as the dense path; see fusion::streaming).
            let row_nn = match (fusion.selection, fusion.calibration_geo) {
                (Selection::RowNn, Calibration::RowSoftmax { tau }) => Some(tau),
                _ => None,
            };
            let c = match (sims, row_nn) {
                (Some(Similarities { image: Some(_), .. }), _) => return Err(mismatch()),
                (Some(s), Some(tau)) => {
                    crate::fusion::streaming::row_nn_from_similarity(&s.geo, tau)?
                }
                (Some(s), None) => match_then_fuse_select(None, Some(&s.geo), &fusion)?,
                (None, Some(tau)) => {
                    crate::fusion::streaming::row_nn_posterior(&src.features, &tgt.features, tau)?
                }
                (None, None) => {
                    let sim = cosine_similarity(&src.features, &tgt.features)?;
                    match_then_fuse_select(None, Some(&sim), &fusion)?
                }
            };
            timer.record("similarity+fusion", t.elapsed(), false);
            c
        }
    };
    let label = inputs
        .image_label
        .as_ref()
        .map(|l| format!("{l}; fusion {:?})", params.fusion.mode));
    finish(pair, params, timer, src, tgt, corr, label)
}

fn mismatch() -> Error {
    Error::Invalid(
        "kept similarities do not match the fusion inputs (image branch on one, off on the other)"
            .into(),
    )
}

/// Pose estimation from `corr` and evaluation against the pair's ground truth.
fn finish(
    pair: &ScanPair,
    params: &RegisterParams,
    mut timer: Timer,
    src: &GeoBranch,
    tgt: &GeoBranch,
    corr: Vec<Correspondence>,
    image_branch: Option<String>,
) -> Result<RegistrationResult> {
    let sp: Vec<Point3<f32>> = corr
        .iter()
        .map(|c| src.keypoints.points[c.src as usize])
        .collect();
    let tp: Vec<Point3<f32>> = corr
        .iter()
        .map(|c| tgt.keypoints.points[c.tgt as usize])
        .collect();
    let w: Vec<f32> = corr.iter().map(|c| c.score).collect();
    let est: Estimate = timer.stage("estimate", || {
        estimate_pose(&sp, &tp, &w, &params.estimator)
    })?;
    let metrics = match pair.gt_target_from_source.as_ref() {
        Some(gt) => Some(PairMetrics::new(
            &est.target_from_source,
            gt,
            crate::metrics::inlier_ratio(&sp, &tp, gt, params.inlier_threshold)?,
        )),
        None => None,
    };
    let total_ms = timer.t0.elapsed().as_secs_f64() * 1e3;
    Ok(RegistrationResult {
        pair_id: pair.id.clone(),
        source_name: pair.source.name.clone(),
        target_name: pair.target.name.clone(),
        target_from_source: matrix_rows(&est.target_from_source),
        estimate: est.target_from_source,
        gt_target_from_source: pair.gt_target_from_source.as_ref().map(matrix_rows),
        metrics,
        estimator: est.method.clone(),
        warnings: est.warning.iter().cloned().collect(),
        geo_features: src.label.clone(),
        image_branch,
        n_source_keypoints: src.keypoints.len(),
        n_target_keypoints: tgt.keypoints.len(),
        n_correspondences: corr.len(),
        n_inliers: est.inliers.len(),
        timings: timer.timings,
        total_ms,
        source_keypoints: src.keypoints.points.clone(),
        target_keypoints: tgt.keypoints.points.clone(),
        correspondences: corr,
        inliers: est.inliers,
        image: None,
    })
}
