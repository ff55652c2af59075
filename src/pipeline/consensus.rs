//! The `consensus` fusion mode in the in-memory tail: each candidate's correspondences
//! (geometry alone, Noisy-AND, image alone) from the same inputs, a pose per candidate, the
//! rule of [`crate::fusion::consensus`] to pick one, and the result with its provenance.

use super::fuse::{
    endpoints, finish_with, geometry_correspondences, image_correspondences, similarities,
    FusionInputs, ImageInputs, Similarities, STREAM_ENTRIES,
};
use super::params::RegisterParams;
use super::result::{matrix_rows, RegistrationResult, Timer};
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::estimate::estimate_pose;
use crate::fusion::consensus::{
    decide, fit, union, Candidate, CandidateReport, ConsensusDecision, CANDIDATES,
};
use crate::fusion::{Correspondence, FusionMode, FusionParams, Selection};
use crate::metrics::PairMetrics;
use std::time::Instant;

/// The fusion parameters of one candidate: geometry alone with row nearest neighbours (the
/// geometry-alone registration's selection), the others with the run's selection.
pub fn candidate_params(fusion: &FusionParams, c: Candidate) -> FusionParams {
    let mut p = *fusion;
    match c {
        Candidate::Geometry => {
            p.mode = FusionMode::GeometryOnly;
            p.selection = Selection::RowNn;
        }
        Candidate::NoisyAnd => p.mode = FusionMode::NoisyAnd,
        Candidate::Image => p.mode = FusionMode::ImageOnly,
    }
    p
}

/// Each of `candidates`' correspondences from `inputs` (the image descriptors required).
/// The similarity matrices are formed once (or taken from `sims`), except for a large pair
/// whose fusion streams from the features.
pub(crate) fn candidate_correspondences(
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    candidates: &[Candidate],
    timer: &mut Timer,
) -> Result<Vec<(Candidate, Vec<Correspondence>)>> {
    if inputs.image.is_none() {
        return Err(Error::Invalid(
            "fusion consensus: the image branch's descriptors are missing".into(),
        ));
    }
    let (n, m) = (
        inputs.source_geo.features.len(),
        inputs.target_geo.features.len(),
    );
    let streams = matches!(inputs.image, Some(ImageInputs::PerImage(..)))
        && n.saturating_mul(m) > STREAM_ENTRIES
        && crate::fusion::streams_from_features(&params.fusion);
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
    let mut out = Vec::with_capacity(candidates.len());
    for &c in candidates {
        let p = candidate_params(&params.fusion, c);
        let t = Instant::now();
        let mut scratch = Timer::new();
        let corr = match c {
            Candidate::Geometry => geometry_correspondences(inputs, sims, &p, &mut scratch)?,
            _ => image_correspondences(params, inputs, sims, &p, &mut scratch)?,
        };
        timer.record(&format!("fusion: {}", c.label()), t.elapsed(), false);
        out.push((c, corr));
    }
    Ok(out)
}

/// [`candidate_correspondences`] without the stage timings (studies of the rule).
pub fn candidate_sets(
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    candidates: &[Candidate],
) -> Result<Vec<(Candidate, Vec<Correspondence>)>> {
    candidate_correspondences(params, inputs, sims, candidates, &mut Timer::new())
}

/// The `consensus` registration of `pair` from `inputs` (image descriptors present).
pub(crate) fn register(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    mut timer: Timer,
) -> Result<RegistrationResult> {
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let sets = candidate_correspondences(params, inputs, sims, CANDIDATES, &mut timer)?;
    let theta = params.inlier_threshold;
    let all: Vec<&[Correspondence]> = sets.iter().map(|(_, c)| c.as_slice()).collect();
    let neutral = union(&all);
    let us: Vec<_> = neutral
        .iter()
        .map(|&(s, _)| src.keypoints.points[s as usize])
        .collect();
    let ut: Vec<_> = neutral
        .iter()
        .map(|&(_, t)| tgt.keypoints.points[t as usize])
        .collect();
    let mut estimated = Vec::new();
    let mut skipped = Vec::new();
    for (c, corr) in sets {
        let (sp, tp, w) = endpoints((src, tgt), &corr);
        let t = Instant::now();
        let est = estimate_pose(&sp, &tp, &w, &params.estimator);
        timer.record(&format!("estimate: {}", c.label()), t.elapsed(), false);
        match est {
            Ok(e) => estimated.push((c, corr, sp, tp, e)),
            Err(e) => skipped.push(format!("{}: {e}", c.label())),
        }
    }
    let fits: Vec<_> = estimated
        .iter()
        .map(|(c, _, _, _, e)| (*c, fit(&e.target_from_source, &us, &ut, theta)))
        .collect();
    let Some((win, decided_by)) = decide(&fits) else {
        return Err(Error::Degenerate(format!(
            "fusion consensus: no candidate could be estimated ({})",
            skipped.join("; ")
        )));
    };
    let candidates = estimated
        .iter()
        .zip(&fits)
        .map(|((c, corr, _, _, e), (_, f))| {
            let m = pair
                .gt_target_from_source
                .as_ref()
                .map(|gt| PairMetrics::new(&e.target_from_source, gt, 0.0));
            CandidateReport {
                candidate: *c,
                n_correspondences: corr.len(),
                estimator_inliers: e.inliers.len(),
                estimator: e.method.clone(),
                fit: *f,
                target_from_source: matrix_rows(&e.target_from_source),
                rre_deg: m.map(|m| m.rre_deg),
                rte_m: m.map(|m| m.rte_m),
                success: m.map(|m| m.success),
            }
        })
        .collect();
    let decision = ConsensusDecision {
        chosen: fits[win].0,
        decided_by,
        threshold_m: theta,
        union_size: neutral.len(),
        candidates,
        skipped,
    };
    let (_, corr, sp, tp, est) = estimated.swap_remove(win);
    let label = inputs
        .image_label
        .as_ref()
        .map(|l| format!("{l}; {})", decision.provenance()));
    let mut res = finish_with(pair, params, timer, (src, tgt), corr, (sp, tp), est, label)?;
    res.warnings.extend(
        decision
            .skipped
            .iter()
            .map(|s| format!("fusion consensus: candidate skipped: {s}")),
    );
    res.consensus = Some(decision);
    Ok(res)
}
