//! Scale hypotheses: the whole registration at the voxels v, 2 v, 4 v, ... (every distance
//! that follows the voxel with it), the pose most consistent with both scans' depth views
//! kept. For LiDAR whose scale no published configuration fixes: a voxel too fine for scans
//! tens of metres apart finds a repeated structure (a street shifted along itself) before the
//! true one.
//!
//! The arbitration is the visibility score V ([`crate::camera::visibility`]: consistent minus
//! conflicting keypoints, as its own protocol fixed it; the `visibility` fusion has since moved
//! to the share of seen keypoints that agree, chosen on indoor pairs): every
//! pose is scored with the same points and distance (the finest hypothesis's keypoints and
//! inlier threshold), so a coarser hypothesis gains nothing from having fewer, larger cells;
//! a tie goes to the finest voxel (the preset's own). The protocol that fixed all of this is
//! in docs/outdoor.md, "Scale hypotheses".

pub use super::arbitration::{ScaleHypothesis, ScaleReport};

use super::graph::{Plan, StageName};
use super::inputs::PairViews;
use super::params::{LidarOrigin, RegisterParams, VirtualCamera};
use super::registration::Registration;
use super::result::{status_word, RegistrationResult, StageTiming};
use super::stages::virtual_frames::{virtual_frames, FrameStore};
use super::tail::visibility::choose;
use crate::camera::visibility::both_ways;
use crate::dataset::{FrameSet, Scan, ScanPair};
use crate::error::{Error, Result};
use crate::estimate::scale::Scaled;
use std::time::Instant;

/// f-theta cameras per scan for the views (90° apart: 360° with the 180° camera).
pub const VIEW_CAMERAS: usize = 4;

/// The voxels of the hypotheses: `params.voxel` times 1, 2, 4, ... (`params.scales` of them,
/// at least one).
pub fn voxels(params: &RegisterParams) -> Vec<f64> {
    (0..params.scales.max(1))
        .map(|k| params.voxel * f64::from(1u32 << k.min(30)))
        .collect()
}

/// `params` as the single-voxel registration of hypothesis `voxel`. The GT inlier-ratio
/// threshold (an evaluation distance, not the estimator's) stays the search's own, so the
/// reported inlier ratio does not depend on the voxel kept.
pub fn hypothesis_params(params: &RegisterParams, voxel: f64) -> RegisterParams {
    RegisterParams {
        voxel,
        scales: 1,
        inlier_threshold: Scaled::Set(params.inlier_threshold_m()),
        ..params.clone()
    }
}

/// A scan's depth views for the arbitration: its sensor frames, else [`VIEW_CAMERAS`]
/// f-theta range images at the sensor position estimated from the scan (its frame's origin
/// when none can be estimated, with a warning).
fn scan_views(store: &mut FrameStore, scan: &Scan, warnings: &mut Vec<String>) -> Result<FrameSet> {
    if let Some(f) = &scan.frames {
        return Ok(f.clone());
    }
    let ftheta = |store: &mut FrameStore, origin| {
        virtual_frames(
            store,
            scan,
            VIEW_CAMERAS,
            VirtualCamera::Ftheta,
            VIEW_CAMERAS,
            origin,
        )
    };
    match ftheta(store, LidarOrigin::Estimated) {
        Ok(f) => Ok(f),
        Err(e) => {
            warnings.push(format!(
                "scales: {}: no sensor position could be estimated ({e}); its range views \
                 stand at the scan frame's origin",
                scan.name
            ));
            ftheta(store, LidarOrigin::ScanOrigin)
        }
    }
}

/// The scale search of `pair` under `reg` (`reg.params.scales` > 1): every hypothesis
/// registered by the single run (`run.rs`), the one with the largest visibility kept.
pub(crate) fn register(reg: &Registration, pair: &ScanPair) -> Result<RegistrationResult> {
    let t0 = Instant::now();
    let voxels = voxels(reg.params);
    let mut results = Vec::with_capacity(voxels.len());
    for &v in &voxels {
        let p = hypothesis_params(reg.params, v);
        let one = Registration {
            params: &p,
            cache: reg.cache,
            memo: reg.memo,
            estimates: None,
            keep: reg.keep,
            generate: reg.generate,
        };
        results.push(one.run_plan(Plan::skeleton(pair, &p), pair)?);
    }

    let t = Instant::now();
    let mut warnings = Vec::new();
    let mut store = FrameStore::new(reg.cache);
    let views = PairViews::new(
        scan_views(&mut store, &pair.source, &mut warnings)?,
        scan_views(&mut store, &pair.target, &mut warnings)?,
    );
    // read now: without a cache the rendered views live in a scratch folder dropped below
    match reg.memo {
        Some(m) => views.load_with(m)?,
        None => views.load()?,
    }
    warnings.append(&mut store.warnings);
    drop(store);
    let [src_views, tgt_views] = views.views()?;
    let finest = results
        .first()
        .ok_or_else(|| Error::Missing("scales: no hypothesis".into()))?;
    // every hypothesis keeps the search's own inlier threshold (`hypothesis_params`)
    let theta = reg.params.inlier_threshold_m();
    let (src_pts, tgt_pts) = (&finest.source_keypoints, &finest.target_keypoints);
    let hypotheses: Vec<ScaleHypothesis> = voxels
        .iter()
        .zip(&results)
        .map(|(&voxel, r)| {
            let v = both_ways(
                (src_pts, tgt_pts),
                &r.estimate,
                (&src_views, &tgt_views),
                theta,
            );
            ScaleHypothesis {
                voxel,
                consistent: v.consistent,
                conflict: v.conflict,
                score: v.score(),
                inliers: r.n_inliers,
            }
        })
        .collect();
    let scores: Vec<i64> = hypotheses.iter().map(|h| h.score).collect();
    let k = choose(&scores).unwrap_or(0);
    if scores.get(k).is_some_and(|&s| s <= 0) {
        // more keypoints in observed free space than on observed surfaces, for every pose
        warnings.push(format!(
            "scales: no hypothesis is consistent with both scans' range views (the best V is \
             {}): the kept pose is likely wrong",
            scores[k]
        ));
    }
    let report = ScaleReport {
        chosen_voxel: voxels[k],
        hypotheses,
        scored_voxel: voxels[0],
        theta,
        source_views: src_views.len(),
        target_views: tgt_views.len(),
    };
    let arbitration_ms = t.elapsed().as_secs_f64() * 1e3;

    // every hypothesis's stages in the timings, each named by its voxel
    let mut timings = Vec::new();
    for (v, r) in voxels.iter().zip(&results) {
        timings.extend(r.timings.iter().map(|s| StageTiming {
            stage: format!("scale {v} m: {}", s.stage),
            ..s.clone()
        }));
    }
    timings.push(StageTiming {
        stage: "scales: visibility".into(),
        name: Some(StageName::Fusion),
        ms: arbitration_ms,
        status: status_word(false).into(),
    });
    let mut res = results.swap_remove(k);
    res.timings = timings;
    res.total_ms = t0.elapsed().as_secs_f64() * 1e3;
    res.warnings.extend(warnings);
    res.scales = Some(report);
    Ok(res)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_octaves_of_the_outdoor_voxel() {
        let p = RegisterParams::preset(crate::dataset::preset::Preset::OutdoorSearch);
        assert_eq!(p.scales, 3);
        let v = voxels(&p);
        assert_eq!(v.len(), 3);
        for (a, b) in v.iter().zip([0.3, 0.6, 1.2]) {
            assert!((a - b).abs() < 1e-12, "{v:?}");
        }
        // every estimator distance that follows the voxel follows each hypothesis's; the GT
        // inlier-ratio threshold stays the search's
        let h = hypothesis_params(&p, v[2]);
        assert_eq!(h.scales, 1);
        match h.estimator_resolved() {
            crate::estimate::EstimatorKind::Sc2Pcr(s) => {
                assert_eq!(s.d_thre, Scaled::Set(2.4f32));
                assert_eq!(s.inlier_threshold, Scaled::Set(2.4f32));
            }
            e => panic!("{e:?}"),
        }
        assert!((h.inlier_threshold_m() - 0.6).abs() < 1e-9);
        // one scale: the voxel alone
        let single = RegisterParams::preset(crate::dataset::preset::Preset::Outdoor);
        assert_eq!(voxels(&single), vec![0.3]);
    }

    #[test]
    fn the_provenance_names_the_kept_voxel_and_every_score() {
        let h = |voxel, score| ScaleHypothesis {
            voxel,
            consistent: 1,
            conflict: 0,
            score,
            inliers: 9,
        };
        let r = ScaleReport {
            chosen_voxel: 1.2,
            hypotheses: vec![h(0.3, -1210), h(0.6, -800), h(1.2, 2310)],
            scored_voxel: 0.3,
            theta: 0.6,
            source_views: 4,
            target_views: 4,
        };
        let p = r.provenance();
        assert!(
            p.starts_with("scales: kept voxel 1.2 m of 0.3, 0.6, 1.2 m"),
            "{p}"
        );
        assert!(p.contains("0.3 m -1210, 0.6 m -800, 1.2 m 2310"), "{p}");
    }
}
