//! The `visibility` fusion mode in the in-memory tail: the `union` pose, the geometric
//! branch's pose (its row-NN set), Noisy-AND's pose and the image branch's pose, each estimated
//! by the run's estimator; the one most consistent with both scans' depth views is kept
//! ([`crate::camera::visibility`]: F, the 95 % lower bound of the share of seen keypoints that
//! lie on an observed surface rather than in observed free space, both directions; ties in the
//! order union, geometry, Noisy-AND, image).
//!
//! Chosen on development pairs by the written protocol (docs/ablation.md, "The fusion study",
//! fourth to sixth rounds): counts of correspondences cannot tell a correct small cluster from
//! a wrong but consistent large one; whether a pose puts one scan into the space the other's
//! views saw through can. The share, not the count (consistent minus conflicting, V), decides:
//! a count grows with the overlap a pose creates, so a pose sliding one scan along a wall could
//! win by it. The share is compared in every depth view the image branch has, the sensor's
//! frames or the virtual frames rendered around a cloud; the report says which.

use super::memo::Memo;
use super::params::RegisterParams;
use super::result::{RegistrationResult, StageTiming, Timer};
use super::tail::{finish, EstimateMemo, FusionInputs, Similarities};
use super::union::{branch_sets, from_sets, geometry_params, image_params, noisy_and_params};
use crate::camera::visibility::{both_ways, DepthView};
use crate::dataset::{FrameSet, ScanPair, ViewOrigin};
use crate::error::{Error, Result};
use crate::io::depth_png::{read_depth_png, DepthImage};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use std::time::Instant;

/// A pose the visibility mode chooses among.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Candidate {
    Union,
    Geometry,
    NoisyAnd,
    Image,
}

impl Candidate {
    /// The tie order.
    pub const ALL: [Candidate; 4] = [
        Candidate::Union,
        Candidate::Geometry,
        Candidate::NoisyAnd,
        Candidate::Image,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Candidate::Union => "union",
            Candidate::Geometry => "geometry",
            Candidate::NoisyAnd => "Noisy-AND",
            Candidate::Image => "image",
        }
    }
}

/// One candidate pose's visibility (source keypoints in the target's views plus target
/// keypoints in the source's views).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CandidateScore {
    pub pose: Candidate,
    pub consistent: usize,
    pub conflict: usize,
    /// V = consistent - conflict (shown; not what decides).
    pub score: i64,
    /// F: the 95 % lower bound of consistent / (consistent + conflict), what decides (0 in a
    /// report written before the share decided).
    #[serde(default)]
    pub share: f64,
    /// The estimator's inliers of this pose on its own correspondences.
    pub inliers: usize,
}

/// What the visibility mode compared and kept: the result's provenance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VisibilityReport {
    pub chosen: Candidate,
    /// Every candidate, in the tie order (none in a report of a version that kept the union's
    /// pose with virtual views without comparing).
    pub candidates: Vec<CandidateScore>,
    /// The depth views each side was checked against.
    pub source_views: usize,
    pub target_views: usize,
    /// Where the views' cameras stand (the weaker side's): the sensor's frames, or a virtual
    /// trajectory around a cloud. Results written before this field existed had sensor views.
    #[serde(default = "sensor_views")]
    pub views: ViewOrigin,
    /// The candidates whose pose could not be estimated (too few correspondences, a degenerate
    /// set), with the reason: left out of the comparison, never fatal while another pose is.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub skipped: Vec<SkippedCandidate>,
}

/// A candidate the visibility mode could not estimate, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkippedCandidate {
    pub pose: Candidate,
    pub reason: String,
}

fn sensor_views() -> ViewOrigin {
    ViewOrigin::Sensor
}

/// The views of a pair as the visibility rule sees them: virtual when either side's are.
pub fn pair_view_origin(source: ViewOrigin, target: ViewOrigin) -> ViewOrigin {
    match (source, target) {
        (ViewOrigin::Virtual, _) | (_, ViewOrigin::Virtual) => ViewOrigin::Virtual,
        (ViewOrigin::SensorPosition, _) | (_, ViewOrigin::SensorPosition) => {
            ViewOrigin::SensorPosition
        }
        _ => ViewOrigin::Sensor,
    }
}

impl VisibilityReport {
    /// "fusion: visibility (kept the image pose; F = 95 % lower bound of the share of seen
    /// keypoints consistent with 50 + 50 sensor depth views: union 0.409, geometry 0.408,
    /// Noisy-AND 0.437, image 0.815)".
    pub fn provenance(&self) -> String {
        if self.candidates.is_empty() {
            return format!(
                "fusion: visibility ({}: kept the {} pose; poses not compared)",
                self.views.label(),
                self.chosen.label()
            );
        }
        let f: Vec<String> = self
            .candidates
            .iter()
            .map(|c| format!("{} {:.3}", c.pose.label(), c.share))
            .collect();
        let skipped: String = self
            .skipped
            .iter()
            .map(|c| format!("; {} pose not estimated: {}", c.pose.label(), c.reason))
            .collect();
        format!(
            "fusion: visibility (kept the {} pose; F = 95 % lower bound of the share of seen \
             keypoints consistent with {} + {} depth views ({}): {}{skipped})",
            self.chosen.label(),
            self.source_views,
            self.target_views,
            self.views.label(),
            f.join(", ")
        )
    }
}

/// Whether a candidate's failure leaves it out of the comparison (an estimate that cannot be
/// made from its correspondences) rather than ending the run (a cancelled run).
fn skippable(e: &Error) -> bool {
    !matches!(e, Error::Cancelled)
}

/// The index of the largest score; ties go to the earliest. None for no scores or a NaN.
pub fn choose<T: PartialOrd + Copy>(scores: &[T]) -> Option<usize> {
    let mut best: Option<(usize, T)> = None;
    for (i, &s) in scores.iter().enumerate() {
        // a NaN is not ordered, not even with itself
        s.partial_cmp(&s)?;
        if best.is_none_or(|(_, b)| s > b) {
            best = Some((i, s));
        }
    }
    best.map(|(i, _)| i)
}

/// The depth frames of both scans of a pair (every frame the image branch has: the sensor's, or
/// the virtual frames rendered for a cloud-only scan), read once, on first use.
#[derive(Debug)]
pub struct PairViews {
    source: FrameSet,
    target: FrameSet,
    loaded: OnceLock<std::result::Result<[Arc<Vec<DepthImage>>; 2], String>>,
}

impl PairViews {
    pub fn new(source: FrameSet, target: FrameSet) -> Self {
        PairViews {
            source,
            target,
            loaded: OnceLock::new(),
        }
    }

    /// Read every depth frame now (the virtual frames of a run without a cache live in a
    /// scratch folder only until the run ends).
    pub fn load(&self) -> Result<()> {
        self.depths(None).map(|_| ())
    }

    /// [`Self::load`], each side's frames taken from `memo` when an earlier pair of the same
    /// scan read them (the same files, unchanged), and kept there for the next.
    pub fn load_with(&self, memo: &Memo) -> Result<()> {
        self.depths(Some(memo)).map(|_| ())
    }

    fn depths(&self, memo: Option<&Memo>) -> Result<&[Arc<Vec<DepthImage>>; 2]> {
        // L PNG decodes per side, in parallel (the same images in the same order)
        let decode = |fs: &FrameSet| -> Result<Vec<DepthImage>> {
            use rayon::prelude::*;
            fs.frames
                .par_iter()
                .map(|f| read_depth_png(&f.depth_path))
                .collect()
        };
        let read = |fs: &FrameSet| -> Result<Arc<Vec<DepthImage>>> {
            match memo {
                Some(m) => {
                    let paths: Vec<PathBuf> =
                        fs.frames.iter().map(|f| f.depth_path.clone()).collect();
                    m.depth_views(&paths, || decode(fs))
                }
                None => decode(fs).map(Arc::new),
            }
        };
        self.loaded
            .get_or_init(|| {
                let both = || -> Result<[Arc<Vec<DepthImage>>; 2]> {
                    let (s, t) = rayon::join(|| read(&self.source), || read(&self.target));
                    Ok([s?, t?])
                };
                both().map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|m| Error::Invalid(format!("fusion visibility: {m}")))
    }

    /// Where the pair's cameras stand ([`pair_view_origin`] of both sides).
    pub fn origin(&self) -> ViewOrigin {
        pair_view_origin(self.source.origin, self.target.origin)
    }

    /// (source views, target views).
    pub fn views(&self) -> Result<[Vec<DepthView<'_>>; 2]> {
        let [sd, td] = self.depths(None)?;
        Ok([side(&self.source, sd), side(&self.target, td)])
    }
}

fn side<'a>(fs: &'a FrameSet, depths: &'a [DepthImage]) -> Vec<DepthView<'a>> {
    fs.frames
        .iter()
        .zip(depths)
        .map(|(f, depth)| DepthView {
            camera: &fs.camera,
            scan_from_camera: f.scan_from_camera,
            depth,
        })
        .collect()
}

/// The `visibility` registration of `pair` from `inputs` (image descriptors and depth views
/// present).
pub(crate) fn register(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    mut timer: Timer,
    memo: Option<&EstimateMemo>,
) -> Result<RegistrationResult> {
    let t0 = timer.t0;
    let views = inputs.views.as_ref().ok_or_else(|| {
        Error::Missing(
            "fusion visibility: the scans' depth views are missing (the image branch did not \
             run on this pair)"
                .into(),
        )
    })?;
    let t = Instant::now();
    let origin = views.origin();
    let [src_views, tgt_views] = views.views()?;
    timer.record("visibility: depth views", t.elapsed(), false);
    let named = [
        ("noisy-and", noisy_and_params(&params.fusion)),
        ("geometry", geometry_params(&params.fusion)),
        ("image", image_params(&params.fusion)),
    ];
    let [and, geo, img] = branch_sets(inputs, sims, &mut timer, named)?;
    let union = from_sets(pair, params, inputs, (&and, &geo), timer, memo);
    let src_tgt = (&inputs.source_geo, &inputs.target_geo);
    let alone = |corr| {
        let label = inputs.image_label.clone();
        finish(pair, params, Timer::new(), src_tgt, corr, label, None)
    };
    // A candidate that cannot be estimated (no correspondences: an image branch that saw
    // nothing, a set too small for SC2-PCR) is left out and reported; the run fails only when
    // no candidate has a pose.
    let results = [union, alone(geo), alone(and), alone(img)];
    let mut skipped = Vec::new();
    let mut first_err = None;
    let mut kept: Vec<(Candidate, RegistrationResult)> = Vec::new();
    for (&pose, r) in Candidate::ALL.iter().zip(results) {
        match r {
            Ok(r) => kept.push((pose, r)),
            Err(e) if skippable(&e) => {
                skipped.push(SkippedCandidate {
                    pose,
                    reason: e.to_string(),
                });
                first_err.get_or_insert(e);
            }
            Err(e) => return Err(e),
        }
    }
    if kept.is_empty() {
        return Err(first_err
            .unwrap_or_else(|| Error::Degenerate("fusion visibility: no candidate pose".into())));
    }

    let t = Instant::now();
    let theta = params.inlier_threshold_m();
    let (src_pts, tgt_pts) = (
        &inputs.source_geo.keypoints.points,
        &inputs.target_geo.keypoints.points,
    );
    let candidates: Vec<CandidateScore> = kept
        .iter()
        .map(|(pose, r)| {
            let v = both_ways(
                (src_pts, tgt_pts),
                &r.estimate,
                (&src_views, &tgt_views),
                theta,
            );
            CandidateScore {
                pose: *pose,
                consistent: v.consistent,
                conflict: v.conflict,
                score: v.score(),
                share: v.share_lower_bound(),
                inliers: r.n_inliers,
            }
        })
        .collect();
    let shares: Vec<f64> = candidates.iter().map(|c| c.share).collect();
    let k = choose(&shares).unwrap_or(0);
    let vis_elapsed = t.elapsed();
    let warnings: Vec<String> = skipped
        .iter()
        .map(|c| {
            format!(
                "fusion visibility: the {} pose could not be estimated and was left out ({})",
                c.pose.label(),
                c.reason
            )
        })
        .collect();
    let report = VisibilityReport {
        chosen: kept[k].0,
        candidates,
        source_views: src_views.len(),
        target_views: tgt_views.len(),
        views: origin,
        skipped,
    };

    // the union's timings (or the first estimated candidate's), then the others' estimates
    let mut timings = kept[0].1.timings.clone();
    for (pose, r) in kept.iter().skip(1) {
        let name = format!("estimate: {} pose", pose.label());
        timings.extend(r.timings.iter().map(|t| StageTiming {
            stage: name.clone(),
            ..t.clone()
        }));
    }
    timings.push(StageTiming {
        stage: "visibility".into(),
        name: Some(super::plan::StageName::Fusion),
        ms: vis_elapsed.as_secs_f64() * 1e3,
        status: super::result::status_word(false).into(),
    });
    let mut res = kept.swap_remove(k).1;
    res.warnings.extend(warnings);
    res.timings = timings;
    Ok(with_report(res, inputs, report, t0))
}

/// The kept result with the run's total time, the report and its provenance in the label.
fn with_report(
    mut res: RegistrationResult,
    inputs: &FusionInputs,
    report: VisibilityReport,
    t0: Instant,
) -> RegistrationResult {
    res.total_ms = t0.elapsed().as_secs_f64() * 1e3;
    res.image_branch = inputs.image_label.as_ref().map(|l| {
        let union = res.union.as_ref().map(|u| format!("; {}", u.provenance()));
        format!("{l}; {}{})", report.provenance(), union.unwrap_or_default())
    });
    res.visibility = Some(report);
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_largest_score_wins_and_ties_go_to_the_earliest() {
        assert_eq!(choose(&[0.41, 0.41, 0.44, 0.82]), Some(3));
        assert_eq!(choose(&[0.5, 0.5, 0.4]), Some(0));
        assert_eq!(choose(&[0.1, 0.7, 0.7]), Some(1));
        assert_eq!(choose::<f64>(&[]), None);
        assert_eq!(choose(&[0.2, f64::NAN]), None);
        // the scale search's integer V
        assert_eq!(choose(&[-399, -323, 2056]), Some(2));
        assert_eq!(choose(&[5, 5, 4]), Some(0));
    }

    #[test]
    fn the_provenance_names_the_kept_pose_the_views_and_every_share() {
        let c = |pose, share| CandidateScore {
            pose,
            consistent: 10,
            conflict: 3,
            score: 7,
            share,
            inliers: 4,
        };
        let r = VisibilityReport {
            chosen: Candidate::Image,
            candidates: vec![
                c(Candidate::Union, 0.4093),
                c(Candidate::Geometry, 0.4082),
                c(Candidate::NoisyAnd, 0.4374),
                c(Candidate::Image, 0.8150),
            ],
            source_views: 50,
            target_views: 50,
            views: ViewOrigin::Sensor,
            skipped: Vec::new(),
        };
        let p = r.provenance();
        assert!(
            p.starts_with("fusion: visibility (kept the image pose"),
            "{p}"
        );
        assert!(
            p.contains("50 + 50 depth views (sensor frames): union 0.409, geometry 0.408, Noisy-AND 0.437, image 0.815)"),
            "{p}"
        );
        let v = VisibilityReport {
            views: ViewOrigin::Virtual,
            ..r.clone()
        };
        assert!(
            v.provenance().contains("(virtual views)"),
            "{}",
            v.provenance()
        );
        // a report of a version that compared nothing with virtual views says so
        let old = VisibilityReport {
            chosen: Candidate::Union,
            candidates: Vec::new(),
            views: ViewOrigin::Virtual,
            ..r
        };
        let p = old.provenance();
        assert!(
            p.starts_with(
                "fusion: visibility (virtual views: kept the union pose; poses not compared"
            ),
            "{p}"
        );
    }

    #[test]
    fn a_pair_is_virtual_when_either_side_is() {
        use ViewOrigin::*;
        for (s, t, want) in [
            (Sensor, Sensor, Sensor),
            (Sensor, SensorPosition, SensorPosition),
            (SensorPosition, SensorPosition, SensorPosition),
            (Virtual, Sensor, Virtual),
            (SensorPosition, Virtual, Virtual),
        ] {
            assert_eq!(pair_view_origin(s, t), want, "{s:?} {t:?}");
            assert_eq!(pair_view_origin(t, s), want, "{t:?} {s:?}");
        }
        assert!(Sensor.is_sensor() && SensorPosition.is_sensor() && !Virtual.is_sensor());
    }

    #[test]
    fn a_report_written_before_the_views_field_reads_as_sensor_views() {
        let old = r#"{"chosen":"noisy-and","candidates":[],"source_views":50,"target_views":50}"#;
        let r: VisibilityReport = serde_json::from_str(old).unwrap();
        assert_eq!(r.views, ViewOrigin::Sensor);
        // ... and one written before the share decided reads with F = 0
        let old = r#"{"chosen":"geometry","candidates":[{"pose":"geometry","consistent":5,"conflict":1,"score":4,"inliers":9}],"source_views":50,"target_views":50}"#;
        let r: VisibilityReport = serde_json::from_str(old).unwrap();
        assert_eq!(r.candidates[0].share, 0.0);
    }
}
