//! What every fusion mode of the in-memory tail shares: its key, the similarity matrices, the
//! estimate memo, the correspondences of the matrix modes and `finish` (estimation and
//! evaluation); and the tail of the matrix modes and of geometry alone.

pub use crate::pipeline::inputs::{FusionInputs, ImageInputs};

use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::estimate::{estimate_pose, Estimate};
use crate::fusion::{cosine_similarity, match_then_fuse_select, Calibration, Correspondence};
use crate::fusion::{FusionMode, Selection};
use crate::matrix::DenseMatrix;
use crate::pipeline::graph::StageName;
use crate::pipeline::inputs::GeoBranch;
use crate::pipeline::params::RegisterParams;
use crate::pipeline::result::{matrix_rows, RegistrationResult, Timer};

use crate::metrics::PairMetrics;
use nalgebra::Point3;
use std::time::{Duration, Instant};

/// The in-memory tail's name in key comparisons (not cached: no folder of that name).
pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: StageName = StageName::Fusion;

/// The tail's key: the keys of its inputs (both scans' geometric branch, then the image
/// descriptors' stage) and every parameter `fuse_and_finish` reads: the fusion (similarity,
/// calibrations, mode, selection), the estimator and the inlier threshold.
pub fn key(params: &RegisterParams, inputs: &[&str]) -> Result<crate::cache::CacheKey> {
    let RegisterParams {
        voxel,
        // the geometric inputs' keys carry these
        geo_features: _,
        fusion,
        estimator,
        inlier_threshold,
        // the image descriptors' key carries it
        image: _,
        // judges the result after the estimate; does not change it
        success: _,
        scales,
    } = params;
    let mut settings = serde_json::json!({
        "fusion": fusion,
        // the resolved values: a threshold that follows the voxel keys as the number it is
        "estimator": estimator.resolved(*voxel),
        "inlier_threshold": inlier_threshold.at(*voxel, crate::estimate::scale::THRESHOLD_PER_VOXEL),
    });
    // a scale search keeps another hypothesis's pose; one scale keys as before
    if let (true, Some(o)) = (*scales > 1, settings.as_object_mut()) {
        o.insert("scales".into(), (*scales).into());
    }
    crate::cache::CacheKey::new(STAGE, VERSION, inputs, &settings)
}

/// The similarity matrices of [`FusionInputs`]: they do not depend on temperature, fusion
/// mode, selection or estimator, so the GUI keeps them between re-fusions (2 x N x M f32).
#[derive(Debug)]
pub struct Similarities {
    /// Image similarity with its row / column validity (None: geometry only).
    pub image: Option<(DenseMatrix, Vec<bool>, Vec<bool>)>,
    pub geo: DenseMatrix,
    /// Each row's maximum of `geo` and its first position, found on the first geometry-only
    /// row-NN re-fusion: they do not depend on the temperature (the row softmax is monotone),
    /// so later ones only sum the row's exponentials.
    geo_row_max: std::sync::OnceLock<Vec<Option<(u32, f32)>>>,
}

impl Similarities {
    /// Kept matrices (`image`: the image similarity with its row / column validity).
    pub fn new(image: Option<(DenseMatrix, Vec<bool>, Vec<bool>)>, geo: DenseMatrix) -> Self {
        Similarities {
            image,
            geo,
            geo_row_max: Default::default(),
        }
    }

    pub(crate) fn geo_row_max(&self) -> &[Option<(u32, f32)>] {
        self.geo_row_max
            .get_or_init(|| crate::fusion::streaming::row_maxima(&self.geo))
    }
}

/// The last estimate `fuse_and_finish` computed and what it was computed from: the
/// estimate is a pure function of the correspondences' endpoints (in their order), the
/// estimator's parameters and, for weighted SVD (chosen, or SC2-PCR's fallback), the scores.
/// SC2-PCR depends on the set of correspondences it uses (the first `max_points`) alone
/// ([`crate::estimate::sc2pcr::canonical_order`]), so a temperature change under NN selection,
/// which reorders the same set, skips the estimator too. The GUI keeps one per pair.
#[derive(Debug, Default)]
pub struct EstimateMemo {
    last: std::sync::Mutex<Option<MemoEntry>>,
}

#[derive(Debug)]
struct MemoEntry {
    /// x, y, z of source then target endpoints, as bits (exact comparison): in the canonical
    /// order when `canonical`, else in the order given.
    ends: Vec<[u32; 6]>,
    canonical: bool,
    method: crate::estimate::EstimatorKind,
    /// The scores (in the order given), when the estimate read them.
    weights: Option<Vec<u32>>,
    /// When `canonical`, its inliers are positions in `ends`.
    est: Estimate,
}

impl EstimateMemo {
    /// [`estimate_pose`], or the remembered estimate when its inputs are the same.
    /// Whether the estimate was remembered is returned with it.
    pub fn estimate(
        &self,
        sp: &[Point3<f32>],
        tp: &[Point3<f32>],
        w: &[f32],
        method: &crate::estimate::EstimatorKind,
    ) -> Result<(Estimate, bool)> {
        let n = sp.len();
        if n != tp.len() || n != w.len() {
            return estimate_pose(sp, tp, w, method).map(|e| (e, false));
        }
        let end = |i: usize| {
            let (a, b) = (sp[i], tp[i]);
            [a.x, a.y, a.z, b.x, b.y, b.z].map(f32::to_bits)
        };
        let bits = |w: &[f32]| w.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
        // SC2-PCR reads the first max_points, as a set (in score order: as a sequence)
        let order = match method {
            crate::estimate::EstimatorKind::Sc2Pcr(p) if !p.score_order => {
                let m = n.min(p.max_points);
                Some(crate::estimate::sc2pcr::canonical_order(&sp[..m], &tp[..m]))
            }
            _ => None,
        };
        if let Ok(last) = self.last.lock() {
            if let Some(m) = last.as_ref().filter(|m| m.method == *method) {
                match (&order, m.canonical) {
                    (Some(o), true) => {
                        if o.len() == m.ends.len()
                            && o.iter().zip(&m.ends).all(|(&i, e)| end(i) == *e)
                        {
                            return Ok((m.est.clone().reindexed(o), true));
                        }
                    }
                    (_, false) => {
                        if m.ends.len() == n
                            && (0..n).all(|i| end(i) == m.ends[i])
                            && m.weights.as_ref().is_none_or(|mw| *mw == bits(w))
                        {
                            return Ok((m.est.clone(), true));
                        }
                    }
                    (None, true) => {}
                }
            }
        }
        let est = estimate_pose(sp, tp, w, method)?;
        let read_scores = matches!(method, crate::estimate::EstimatorKind::WeightedSvd)
            || est.method.starts_with("weighted-svd");
        // SC2-PCR's own result (not its fallback) is the set's
        let entry = match order.filter(|_| est.method == "sc2pcr") {
            Some(o) => {
                let mut position = vec![0usize; n];
                for (k, &i) in o.iter().enumerate() {
                    position[i] = k;
                }
                let mut kept = est.clone();
                kept.inliers = est.inliers.iter().map(|&i| position[i]).collect();
                MemoEntry {
                    ends: o.iter().map(|&i| end(i)).collect(),
                    canonical: true,
                    method: method.clone(),
                    weights: None,
                    est: kept,
                }
            }
            None => MemoEntry {
                ends: (0..n).map(end).collect(),
                canonical: false,
                method: method.clone(),
                weights: read_scores.then(|| bits(w)),
                est: est.clone(),
            },
        };
        if let Ok(mut last) = self.last.lock() {
            *last = Some(entry);
        }
        Ok((est, false))
    }
}

/// Above this many source x target entries, a registration without kept similarities
/// (`fuse_and_finish` with `sims` None) under the configuration the fused kernel handles
/// ([`crate::fusion::streams_from_features`]) forms the similarity rows band by band from the
/// features instead of holding the two N x M matrices (same correspondences): 2^27 entries is
/// 512 MiB per f32 matrix. An outdoor LiDAR pair at a 0.3 m voxel has about 45k x 45k
/// keypoints, 8 GB per matrix.
pub const STREAM_ENTRIES: usize = 1 << 27;

/// Both similarity matrices of `inputs`.
pub fn similarities(inputs: &FusionInputs) -> Result<Similarities> {
    let geo = cosine_similarity(&inputs.source_geo.features, &inputs.target_geo.features)?;
    let image = match &inputs.image {
        Some(im) => Some(im.similarity()?),
        None => None,
    };
    Ok(Similarities::new(image, geo))
}

/// The tail of a matrix fusion mode (or geometry alone: image None, streaming row-NN when the
/// calibration allows it) from [`FusionInputs`]; `super::fuse_and_finish` chooses it.
pub(crate) fn fuse_matrix_mode(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    mut timer: Timer,
    memo: Option<&EstimateMemo>,
) -> Result<RegistrationResult> {
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let corr = match &inputs.image {
        Some(_) => image_correspondences(inputs, sims, &params.fusion, &mut timer)?,
        None => {
            let mut fusion = params.fusion;
            fusion.mode = FusionMode::GeometryOnly;
            geometry_correspondences(inputs, sims, &fusion, &mut timer)?
        }
    };
    let label = inputs
        .image_label
        .as_ref()
        .map(|l| format!("{l}; fusion {:?})", params.fusion.mode));
    finish(pair, params, timer, (src, tgt), corr, label, memo)
}

/// The correspondences of a fusion with both branches (`fusion.mode` one of the matrix
/// modes): streamed from the features for large pairs without kept matrices, else from the
/// kept or computed similarity matrices.
pub(crate) fn image_correspondences(
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    fusion: &crate::fusion::FusionParams,
    timer: &mut Timer,
) -> Result<Vec<Correspondence>> {
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let Some(image) = &inputs.image else {
        return Err(mismatch());
    };
    if let (ImageInputs::PerImage(fs, vs, ft, vt), None) = (image, sims) {
        if src.features.len().saturating_mul(tgt.features.len()) > STREAM_ENTRIES {
            let t = Instant::now();
            let c = crate::fusion::match_then_fuse_select_features(
                (fs, vs, ft, vt),
                (&src.features, &tgt.features),
                fusion,
            )?;
            if let Some(c) = c {
                timer.record("similarity+fusion", t.elapsed(), false);
                return Ok(c);
            }
        }
    }
    let t = Instant::now();
    let computed;
    let (s_img, v_src, v_tgt, s_geo) = match sims {
        Some(Similarities {
            image: Some((s, vs, vt)),
            geo,
            ..
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
    let corr =
        match_then_fuse_select(Some((s_img, Some(v_src), Some(v_tgt))), Some(s_geo), fusion)?;
    timer.record("fusion", t.elapsed(), false);
    Ok(corr)
}

/// The correspondences of the geometric branch alone (`fusion.mode` GeometryOnly). With image
/// inputs (the union's geometric set) `sims` may be a fused run's kept matrices.
pub(crate) fn geometry_correspondences(
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    fusion: &crate::fusion::FusionParams,
    timer: &mut Timer,
) -> Result<Vec<Correspondence>> {
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let t = Instant::now();
    // Row softmax keeps each row's argmax, so nearest-neighbour selection needs no
    // N x M matrix (same result as the dense path; see fusion::streaming).
    let row_nn = match (fusion.selection, fusion.calibration_geo) {
        (Selection::RowNn, Calibration::RowSoftmax { tau }) => Some(tau),
        _ => None,
    };
    let c = match (sims, row_nn) {
        (Some(Similarities { image: Some(_), .. }), _) if inputs.image.is_none() => {
            return Err(mismatch())
        }
        (Some(s), Some(tau)) => {
            crate::fusion::streaming::row_nn_from_maxima(&s.geo, s.geo_row_max(), tau)?
        }
        (Some(s), None) => match_then_fuse_select(None, Some(&s.geo), fusion)?,
        (None, Some(tau)) => {
            crate::fusion::streaming::row_nn_posterior(&src.features, &tgt.features, tau)?
        }
        (None, None) => {
            let sim = cosine_similarity(&src.features, &tgt.features)?;
            match_then_fuse_select(None, Some(&sim), fusion)?
        }
    };
    timer.record("similarity+fusion", t.elapsed(), false);
    Ok(c)
}

fn mismatch() -> Error {
    Error::Shape(
        "kept similarities do not match the fusion inputs (image branch on one, off on the other)"
            .into(),
    )
}

/// The endpoints and scores of `corr`.
pub fn endpoints(
    (src, tgt): (&GeoBranch, &GeoBranch),
    corr: &[Correspondence],
) -> (Vec<Point3<f32>>, Vec<Point3<f32>>, Vec<f32>) {
    let sp: Vec<Point3<f32>> = corr
        .iter()
        .map(|c| src.keypoints.points[c.src as usize])
        .collect();
    let tp: Vec<Point3<f32>> = corr
        .iter()
        .map(|c| tgt.keypoints.points[c.tgt as usize])
        .collect();
    let w: Vec<f32> = corr.iter().map(|c| c.score).collect();
    (sp, tp, w)
}

/// Pose estimation from `corr` and evaluation against the pair's ground truth.
pub(crate) fn finish(
    pair: &ScanPair,
    params: &RegisterParams,
    mut timer: Timer,
    (src, tgt): (&GeoBranch, &GeoBranch),
    corr: Vec<Correspondence>,
    image_branch: Option<String>,
    memo: Option<&EstimateMemo>,
) -> Result<RegistrationResult> {
    for (side, scan, kp) in [
        ("source", &pair.source, &src.keypoints),
        ("target", &pair.target, &tgt.keypoints),
    ] {
        if let Some(why) = crate::estimate::kabsch::keypoint_problem(&kp.points) {
            return Err(Error::Degenerate(format!(
                "pair {}: the {side} {} {why}; no pose can be estimated from it",
                pair.id, scan.name
            )));
        }
    }
    let (sp, tp, w) = endpoints((src, tgt), &corr);
    let est: Estimate = match memo {
        Some(m) => {
            let t = Instant::now();
            let (est, hit) = m.estimate(&sp, &tp, &w, &params.estimator_resolved())?;
            timer.record("estimate", t.elapsed(), hit);
            est
        }
        None => timer.stage("estimate", || {
            estimate_pose(&sp, &tp, &w, &params.estimator_resolved())
        })?,
    };
    let metrics = match pair.gt_target_from_source.as_ref() {
        Some(gt) => Some(PairMetrics::judged(
            &est.target_from_source,
            gt,
            crate::metrics::inlier_ratio(&sp, &tp, gt, params.inlier_threshold_m())?,
            &params.success,
        )),
        None => None,
    };
    let convention = pair.gt_target_from_source.as_ref().and_then(|gt| {
        crate::metrics::convention::check_gt_convention(
            &src.keypoints.points,
            &tgt.keypoints.points,
            &sp,
            &tp,
            gt,
            params.inlier_threshold_m(),
        )
    });
    let mut warnings: Vec<String> = pair.source.notes.clone();
    warnings.extend(pair.target.notes.iter().cloned());
    warnings.extend(est.warning.iter().cloned());
    warnings.extend(convention.as_ref().and_then(|c| c.warning.clone()));
    let total_ms = timer.t0.elapsed().as_secs_f64() * 1e3;
    Ok(RegistrationResult {
        pair_id: pair.id.clone(),
        source_name: pair.source.name.clone(),
        target_name: pair.target.name.clone(),
        target_from_source: matrix_rows(&est.target_from_source),
        estimate: est.target_from_source,
        gt_target_from_source: pair.gt_target_from_source.as_ref().map(matrix_rows),
        metrics,
        gt_inlier_threshold_m: params.inlier_threshold_m(),
        convention,
        estimator: est.method.clone(),
        warnings,
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
        union: None,
        visibility: None,
        scales: None,
        inputs: None,
        plan: None,
    })
}

#[cfg(test)]
mod memo_tests {
    use super::*;
    use crate::estimate::{EstimatorKind, Sc2PcrParams};

    fn same(a: &Estimate, b: &Estimate) -> bool {
        a.target_from_source.to_homogeneous() == b.target_from_source.to_homogeneous()
            && a.inliers == b.inliers
            && a.method == b.method
            && a.warning == b.warning
    }

    /// The memo gives what `estimate_pose` gives, and only for the same inputs: the same
    /// estimator and endpoints (SC2-PCR: the same set of the ones it uses; otherwise in the same
    /// order); the scores too where they are read.
    #[test]
    fn the_memo_repeats_only_what_it_was_computed_from() {
        let s = crate::estimate::synthetic::synthetic_correspondences(3000, 400, 0.3, 0.01, 7);
        let (sp, tp) = (s.src.clone(), s.tgt.clone());
        let w: Vec<f32> = (0..sp.len()).map(|i| 1.0 / (1.0 + i as f32)).collect();
        let sc2 = EstimatorKind::Sc2Pcr(Sc2PcrParams::default());
        let memo = EstimateMemo::default();
        let (a, hit) = memo.estimate(&sp, &tp, &w, &sc2).unwrap();
        assert!(!hit);
        assert!(same(&a, &estimate_pose(&sp, &tp, &w, &sc2).unwrap()));
        // other scores: SC2-PCR does not read them
        let w2: Vec<f32> = w.iter().map(|x| x * 0.5).collect();
        let (b, hit) = memo.estimate(&sp, &tp, &w2, &sc2).unwrap();
        assert!(hit && same(&a, &b));
        // another order of the same set is the same input to SC2-PCR, its inliers reindexed
        let (mut sr, mut tr) = (sp.clone(), tp.clone());
        sr.swap(0, 1);
        tr.swap(0, 1);
        let (c, hit) = memo.estimate(&sr, &tr, &w, &sc2).unwrap();
        assert!(hit);
        assert!(same(&c, &estimate_pose(&sr, &tr, &w, &sc2).unwrap()));
        // another set is another input
        let (c, hit) = memo.estimate(&sp[1..], &tp[1..], &w[1..], &sc2).unwrap();
        assert!(!hit);
        assert!(same(
            &c,
            &estimate_pose(&sp[1..], &tp[1..], &w[1..], &sc2).unwrap()
        ));
        // beyond max_points only the first ones count, and which they are
        let few = EstimatorKind::Sc2Pcr(Sc2PcrParams {
            max_points: 200,
            ..Default::default()
        });
        let (e, hit) = memo.estimate(&sp, &tp, &w, &few).unwrap();
        assert!(!hit);
        let (mut sr, mut tr) = (sp.clone(), tp.clone());
        sr[200..].reverse();
        tr[200..].reverse();
        let (f, hit) = memo.estimate(&sr, &tr, &w, &few).unwrap();
        assert!(hit && same(&e, &f));
        sr.swap(0, 300);
        tr.swap(0, 300);
        let (f, hit) = memo.estimate(&sr, &tr, &w, &few).unwrap();
        assert!(!hit);
        assert!(same(&f, &estimate_pose(&sr, &tr, &w, &few).unwrap()));
        // weighted SVD reads the scores
        let svd = EstimatorKind::WeightedSvd;
        let (_, hit) = memo.estimate(&sp, &tp, &w, &svd).unwrap();
        assert!(!hit);
        let (_, hit) = memo.estimate(&sp, &tp, &w, &svd).unwrap();
        assert!(hit);
        let (d, hit) = memo.estimate(&sp, &tp, &w2, &svd).unwrap();
        assert!(!hit);
        assert!(same(&d, &estimate_pose(&sp, &tp, &w2, &svd).unwrap()));
    }
}
