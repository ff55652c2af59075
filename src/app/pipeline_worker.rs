//! The inspector's pipeline worker: owns a dataset, runs [`register_pair`] for the selected
//! pair with the UI's settings on the worker thread, and turns the result into an
//! [`InspectorModel`].
//!
//! Model conventions: `model.source` / `model.target` start with the registration keypoints
//! (so `MatchInfo::src` / `tgt` are keypoint indices), followed by a strided subsample of the
//! full scan for display. Clouds stay in their own scan frames; `estimated` and
//! `ground_truth` are target_from_source.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use nalgebra::{Isometry3, Point3};

use super::controls::{
    Calibration as UiCalibration, Command, Estimator, EventSink, FusionMode as UiFusion, LogLevel,
    PipelineSettings, SelectionRule, Worker, WorkerEvent,
};
use super::model::{
    Branch, InspectorModel, MatchInfo, PairEntry, PairStatus, PlotData, Posterior, PrCurve,
    RgbImage, StageInfo, StageState, ViewImage, ViewLabel,
};
use crate::dataset::manifest::Dataset;
use crate::dataset::ScanPair;
use crate::estimate::ransac::RansacParams;
use crate::estimate::sc2pcr::Sc2PcrParams;
use crate::estimate::EstimatorKind;
use crate::fusion::calibrate::Calibration;
use crate::fusion::fuse::FusionMode;
use crate::fusion::select::Selection;
use crate::pipeline::register::{fpfh_branch, GeoBranch};
use crate::pipeline::{register_pair, RegisterParams, RegistrationResult};

/// Inlier threshold of the GT flags on correspondences (metres).
pub const GT_INLIER_M: f64 = 0.10;
/// Display points per cloud on top of the keypoints.
pub const DISPLAY_POINTS: usize = 150_000;
/// Top-k of the "Top-k by score" selection rule.
const TOPK: usize = 8000;
/// Candidates kept per posterior.
const POSTERIOR_CANDIDATES: usize = 400;

/// Why the image branch is not shown, when it is not.
pub const IMAGE_BRANCH_OFF: &str = "image branch: not available for this pair/build — \
register_pair ran the geometric branch only (no generated, oracle or built-in views were \
produced), so there are no views to show and the fused posterior equals the geometric one";

/// Maps the UI's settings onto the pipeline's parameters. `base` carries what the UI does not
/// edit (voxel, geometric feature source, inlier threshold).
pub fn settings_to_params(s: &PipelineSettings, base: &RegisterParams) -> RegisterParams {
    let mut p = base.clone();
    let cal = |c: &super::controls::BranchCalibration| match c.method {
        UiCalibration::DualSoftmax => Calibration::DualSoftmax {
            tau: c.temperature.max(1e-4),
        },
        // "None" has no pipeline equivalent; a row softmax with the given temperature is the
        // closest calibrated posterior
        UiCalibration::Softmax | UiCalibration::None => Calibration::RowSoftmax {
            tau: c.temperature.max(1e-4),
        },
    };
    p.fusion.calibration_img = cal(&s.image_calibration);
    p.fusion.calibration_geo = cal(&s.geometry_calibration);
    p.fusion.mode = match s.fusion {
        UiFusion::NoisyAnd => FusionMode::NoisyAnd,
        UiFusion::NoisyOr => FusionMode::NoisyOr,
        UiFusion::Concatenation => FusionMode::Concat,
        UiFusion::ImageOnly => FusionMode::ImageOnly,
        UiFusion::GeometryOnly => FusionMode::GeometryOnly,
    };
    p.fusion.selection = match s.selection {
        SelectionRule::MutualNearest => Selection::MutualNn,
        SelectionRule::TopK => Selection::TopK(TOPK),
        SelectionRule::RowNearest => Selection::RowNn,
    };
    p.estimator = match s.estimator {
        Estimator::Sc2Pcr => EstimatorKind::Sc2Pcr(Sc2PcrParams::default()),
        Estimator::Ransac => EstimatorKind::Ransac(RansacParams::default()),
    };
    p
}

/// UI settings that reproduce `p` as closely as the controls allow (initial control state).
pub fn params_to_settings(p: &RegisterParams) -> PipelineSettings {
    let mut s = PipelineSettings::default();
    let cal = |c: Calibration| match c {
        Calibration::RowSoftmax { tau } => super::controls::BranchCalibration {
            method: UiCalibration::Softmax,
            temperature: tau,
        },
        Calibration::DualSoftmax { tau } => super::controls::BranchCalibration {
            method: UiCalibration::DualSoftmax,
            temperature: tau,
        },
    };
    s.image_calibration = cal(p.fusion.calibration_img);
    s.geometry_calibration = cal(p.fusion.calibration_geo);
    s.fusion = match p.fusion.mode {
        FusionMode::NoisyAnd => UiFusion::NoisyAnd,
        FusionMode::NoisyOr => UiFusion::NoisyOr,
        FusionMode::Concat => UiFusion::Concatenation,
        FusionMode::ImageOnly => UiFusion::ImageOnly,
        FusionMode::GeometryOnly => UiFusion::GeometryOnly,
    };
    s.selection = match p.fusion.selection {
        Selection::MutualNn => SelectionRule::MutualNearest,
        Selection::TopK(_) => SelectionRule::TopK,
        Selection::RowNn => SelectionRule::RowNearest,
    };
    s.estimator = match p.estimator {
        EstimatorKind::Ransac(_) => Estimator::Ransac,
        _ => Estimator::Sc2Pcr,
    };
    s
}

fn p3(p: &Point3<f32>) -> [f32; 3] {
    [p.x, p.y, p.z]
}

/// Keypoints then a strided subsample of the full cloud, at most `DISPLAY_POINTS` extra.
fn display_cloud(keypoints: &[Point3<f32>], full: &[Point3<f32>], cap: usize) -> Vec<[f32; 3]> {
    let stride = full.len().div_ceil(cap.max(1)).max(1);
    let mut out = Vec::with_capacity(keypoints.len() + full.len() / stride + 1);
    out.extend(keypoints.iter().map(p3));
    out.extend(full.iter().step_by(stride).map(p3));
    out
}

/// Precision-recall of the matches over the score threshold, points (recall, precision).
pub fn pr_curve(name: &str, matches: &[MatchInfo]) -> Option<PrCurve> {
    let mut scored: Vec<(f32, bool)> = matches
        .iter()
        .filter_map(|m| m.inlier_gt.map(|i| (m.score, i)))
        .collect();
    let total = scored.iter().filter(|x| x.1).count();
    if total == 0 {
        return None;
    }
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    let step = (scored.len() / 60).max(1);
    let mut tp = 0usize;
    let mut points = Vec::new();
    for (i, (_, inl)) in scored.iter().enumerate() {
        tp += *inl as usize;
        if (i + 1) % step == 0 || i + 1 == scored.len() {
            points.push([tp as f64 / total as f64, tp as f64 / (i + 1) as f64]);
        }
    }
    Some(PrCurve {
        name: name.into(),
        points,
    })
}

/// Converts a registration result and its pair into the inspector's model. `pairs` is the
/// pair browser (the current pair's row is updated here).
pub fn result_to_model(
    pair: &ScanPair,
    result: &RegistrationResult,
    fusion_label: &str,
    mut pairs: Vec<PairEntry>,
) -> InspectorModel {
    let source = display_cloud(
        &result.source_keypoints,
        &pair.source.cloud.points,
        DISPLAY_POINTS,
    );
    let target = display_cloud(
        &result.target_keypoints,
        &pair.target.cloud.points,
        DISPLAY_POINTS,
    );
    let gt = pair.gt_target_from_source;
    let mut survived = vec![false; result.correspondences.len()];
    for &i in &result.inliers {
        if let Some(s) = survived.get_mut(i) {
            *s = true;
        }
    }
    let matches: Vec<MatchInfo> = result
        .correspondences
        .iter()
        .enumerate()
        .filter_map(|(ci, c)| {
            let (s, t) = (c.src as usize, c.tgt as usize);
            let sp = result.source_keypoints.get(s)?;
            let tp = result.target_keypoints.get(t)?;
            let inlier_gt = gt.map(|g| {
                let q = g * sp.cast::<f64>();
                (q - tp.cast::<f64>()).norm() < GT_INLIER_M
            });
            Some(MatchInfo {
                src: s,
                tgt: t,
                score: c.score.clamp(0.0, 1.0),
                inlier_gt,
                branch: if result.image_branch.is_some() {
                    Branch::Both
                } else {
                    Branch::Geometry
                },
                survived: Some(survived[ci]),
            })
        })
        .collect();

    let (source_views, target_views, note) = match &result.image {
        Some(img) => {
            let prov = &img.provenance;
            let mk = |views: &[crate::pipeline::ViewInfo],
                      links: &[Option<crate::vfm::lift::PixelLink>],
                      is_src: bool| {
                views
                    .iter()
                    .enumerate()
                    .map(|(vi, v)| {
                        let match_pixels = matches
                            .iter()
                            .map(|m| {
                                let k = if is_src { m.src } else { m.tgt };
                                links
                                    .get(k)
                                    .copied()
                                    .flatten()
                                    .filter(|l| l.view as usize == vi)
                                    .map(|l| [l.u as f32, l.v as f32])
                            })
                            .collect();
                        ViewImage {
                            label: ViewLabel {
                                backend: format!("{} ({})", prov.backend, prov.model),
                                prompt: prov.prompt.clone(),
                                cache_entry: format!(
                                    "{} · generated frame {} · depth frame {}",
                                    v.label, v.generated_index, v.depth_index
                                ),
                            },
                            rgb: RgbImage {
                                width: v.image.width(),
                                height: v.image.height(),
                                pixels: v.image.as_raw().clone(),
                            },
                            depth: None,
                            camera: None,
                            match_pixels,
                        }
                    })
                    .collect::<Vec<_>>()
            };
            let s = mk(&img.source_views, &img.source_links, true);
            let t = mk(&img.target_views, &img.target_links, false);
            let note = if s.is_empty() && t.is_empty() {
                Some("image branch ran but selected no views".to_string())
            } else {
                None
            };
            (s, t, note)
        }
        None => (Vec::new(), Vec::new(), Some(IMAGE_BRANCH_OFF.to_string())),
    };

    let stages = result
        .timings
        .iter()
        .map(|t| StageInfo {
            name: t.stage.clone(),
            state: if t.status == "cached" {
                StageState::Cached
            } else {
                StageState::Done
            },
            time_ms: Some(t.ms),
        })
        .collect();

    let (rre, rte) = match &result.metrics {
        Some(m) => (Some(m.rre_deg), Some(m.rte_m)),
        None => (None, None),
    };
    let current = match pairs.iter().position(|p| p.id == result.pair_id) {
        Some(i) => i,
        None => {
            pairs.push(PairEntry {
                id: result.pair_id.clone(),
                status: PairStatus::Pending,
                rre_deg: None,
                rte_m: None,
            });
            pairs.len() - 1
        }
    };
    pairs[current].status = PairStatus::Done;
    pairs[current].rre_deg = rre;
    pairs[current].rte_m = rte;

    let plots = PlotData {
        pr_curves: pr_curve(fusion_label, &matches).into_iter().collect(),
        vs_k: Vec::new(),
        prompt_study: Vec::new(),
    };
    InspectorModel {
        pairs,
        current_pair: Some(current),
        source,
        target,
        initial: Isometry3::identity(),
        estimated: Some(result.estimate),
        ground_truth: gt,
        matches,
        source_views,
        target_views,
        posteriors: Vec::new(),
        stages,
        plots,
        generation_missing: None,
        image_branch_note: note,
    }
}

/// Geometric posterior of source keypoint `src` over the target keypoints: row softmax of the
/// cosine similarities at temperature `tau`, the `POSTERIOR_CANDIDATES` most likely kept.
/// With the image branch off, the fused posterior is the geometric one and the image row is
/// empty.
pub fn geometric_posterior(
    src_branch: &GeoBranch,
    tgt_branch: &GeoBranch,
    src: usize,
    tau: f32,
    gt: Option<&Isometry3<f64>>,
    survived: Option<bool>,
) -> Option<Posterior> {
    if src >= src_branch.features.len() || tgt_branch.features.is_empty() {
        return None;
    }
    let sf = src_branch.features.row(src);
    let ns = sf.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
    let sims: Vec<f32> = (0..tgt_branch.features.len())
        .map(|j| {
            let tf = tgt_branch.features.row(j);
            let nt = tf.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
            sf.iter().zip(tf).map(|(a, b)| a * b).sum::<f32>() / (ns * nt)
        })
        .collect();
    let m = sims.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
    let e: Vec<f32> = sims.iter().map(|s| ((s - m) / tau).exp()).collect();
    let z: f32 = e.iter().sum::<f32>().max(1e-30);
    let mut idx: Vec<usize> = (0..e.len()).collect();
    idx.sort_by(|&a, &b| e[b].total_cmp(&e[a]));
    idx.truncate(POSTERIOR_CANDIDATES);
    let gt_target = gt.map(|g| {
        let q = g * src_branch.keypoints.points[src].cast::<f64>();
        let mut best = (0, f64::INFINITY);
        for (j, t) in tgt_branch.keypoints.points.iter().enumerate() {
            let d = (t.cast::<f64>() - q).norm_squared();
            if d < best.1 {
                best = (j, d);
            }
        }
        best.0
    });
    let mut candidates = idx.clone();
    if let Some(g) = gt_target {
        if !candidates.contains(&g) {
            candidates.push(g);
        }
    }
    let geometric: Vec<f32> = candidates.iter().map(|&j| e[j] / z).collect();
    Some(Posterior {
        source_point: src,
        source_pixel: None,
        source_view: 0,
        candidate_pixels: vec![None; candidates.len()],
        candidates,
        image: Vec::new(),
        fused: geometric.clone(),
        geometric,
        target_view: 0,
        gt_target,
        survived,
    })
}

/// A pair loaded and registered, kept for re-runs and posterior requests.
struct Current {
    pair: ScanPair,
    result: RegistrationResult,
    model: InspectorModel,
    branches: Option<(GeoBranch, GeoBranch)>,
}

/// The [`Worker`] behind `cgenreg inspect`.
pub struct PipelineWorker {
    dataset: Dataset,
    base: RegisterParams,
    settings: PipelineSettings,
    pairs: Vec<PairEntry>,
    current: Option<Current>,
    /// Loaded pairs by id (loading a fragment is the slowest step for real scans).
    loaded: HashMap<String, ScanPair>,
}

impl PipelineWorker {
    pub fn new(dataset: Dataset, base: RegisterParams) -> Self {
        let pairs = dataset
            .pairs()
            .iter()
            .map(|p| PairEntry {
                id: p.id.clone(),
                status: PairStatus::Pending,
                rre_deg: None,
                rte_m: None,
            })
            .collect();
        let mut settings = params_to_settings(&base);
        // register_pair runs the geometric branch only (it forces geometry-only fusion): show
        // what actually ran
        settings.fusion = UiFusion::GeometryOnly;
        Self {
            dataset,
            base,
            settings,
            pairs,
            current: None,
            loaded: HashMap::new(),
        }
    }

    /// Opens a manifest file.
    pub fn open_manifest(path: &std::path::Path, base: RegisterParams) -> crate::Result<Self> {
        Ok(Self::new(Dataset::load(path)?, base))
    }

    pub fn pair_ids(&self) -> Vec<String> {
        self.pairs.iter().map(|p| p.id.clone()).collect()
    }

    /// The model shown before the first result: the pair list and pending stages.
    pub fn initial_model(&self, pair: Option<&str>) -> InspectorModel {
        let mut pairs = self.pairs.clone();
        let current = pair.and_then(|id| pairs.iter().position(|p| p.id == id));
        if let Some(i) = current {
            pairs[i].status = PairStatus::Running;
        }
        InspectorModel {
            pairs,
            current_pair: current,
            stages: vec![StageInfo {
                name: "load + register".into(),
                state: StageState::Running,
                time_ms: None,
            }],
            image_branch_note: Some(IMAGE_BRANCH_OFF.to_string()),
            ..Default::default()
        }
    }

    /// Records a pair that could not be registered (shown as failed in the browser).
    pub fn mark_failed(&mut self, id: &str, why: &str) {
        if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
            p.status = PairStatus::Failed(why.to_string());
        }
    }

    pub fn settings(&self) -> &PipelineSettings {
        &self.settings
    }

    /// Loads (or reuses) and registers one pair; returns the model. Synchronous.
    pub fn run_pair(&mut self, id: &str) -> crate::Result<InspectorModel> {
        let pair = match self.loaded.get(id) {
            Some(p) => p.clone(),
            None => {
                let p = self.dataset.load_pair(id)?;
                self.loaded.insert(id.to_string(), p.clone());
                p
            }
        };
        let params = settings_to_params(&self.settings, &self.base);
        let result = register_pair(&pair, &params)?;
        let label = match &result.image_branch {
            Some(b) => format!("{} · {b}", self.settings.fusion.label()),
            None => format!("geometry only ({}; image branch off)", result.geo_features),
        };
        let model = result_to_model(&pair, &result, &label, self.pairs.clone());
        self.pairs = model.pairs.clone();
        self.current = Some(Current {
            pair,
            result,
            model: model.clone(),
            branches: None,
        });
        Ok(model)
    }

    /// Adds the geometric posterior of source keypoint `src` to the current model.
    pub fn inspect_point(&mut self, src: usize) -> crate::Result<InspectorModel> {
        let tau = match settings_to_params(&self.settings, &self.base)
            .fusion
            .calibration_geo
        {
            Calibration::RowSoftmax { tau } | Calibration::DualSoftmax { tau } => tau,
        };
        let voxel = self.base.voxel;
        let cur = self
            .current
            .as_mut()
            .ok_or_else(|| crate::Error::Invalid("no registered pair to inspect".into()))?;
        if src >= cur.result.source_keypoints.len() {
            return Err(crate::Error::Invalid(format!(
                "point {src} is a display point, not a keypoint (keypoints: 0..{}); click a matched point",
                cur.result.source_keypoints.len()
            )));
        }
        if cur.branches.is_none() {
            if self.base.geo_features != crate::pipeline::params::GeoFeatureSource::Fpfh {
                return Err(crate::Error::Invalid(
                    "posteriors are computed for FPFH features only in this build".into(),
                ));
            }
            let s = fpfh_branch(&cur.pair.source.cloud, voxel)?;
            let t = fpfh_branch(&cur.pair.target.cloud, voxel)?;
            cur.branches = Some((s, t));
        }
        let Some((s, t)) = cur.branches.as_ref() else {
            return Err(crate::Error::Invalid("features unavailable".into()));
        };
        let survived = cur
            .model
            .matches
            .iter()
            .find(|m| m.src == src)
            .and_then(|m| m.survived);
        let post = geometric_posterior(
            s,
            t,
            src,
            tau,
            cur.pair.gt_target_from_source.as_ref(),
            survived,
        )
        .ok_or_else(|| crate::Error::Invalid(format!("no features for source keypoint {src}")))?;
        cur.model.posteriors.retain(|p| p.source_point != src);
        cur.model.posteriors.push(post);
        Ok(cur.model.clone())
    }

    fn run_and_report(&mut self, id: &str, events: &EventSink) {
        events.send(WorkerEvent::Stage(StageInfo {
            name: "load + register".into(),
            state: StageState::Running,
            time_ms: None,
        }));
        if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
            p.status = PairStatus::Running;
        }
        let t = Instant::now();
        match self.run_pair(id) {
            Ok(mut model) => {
                let ms = t.elapsed().as_secs_f64() * 1e3;
                model.stages.insert(
                    0,
                    StageInfo {
                        name: "load + register".into(),
                        state: StageState::Done,
                        time_ms: Some(ms),
                    },
                );
                let msg = match (model.current_pair.and_then(|i| model.pairs.get(i)), ms) {
                    (
                        Some(PairEntry {
                            rre_deg: Some(r),
                            rte_m: Some(e),
                            ..
                        }),
                        ms,
                    ) => format!(
                        "{id}: RRE {r:.2}° RTE {:.1} cm, {} matches, {ms:.0} ms",
                        e * 100.0,
                        model.matches.len()
                    ),
                    _ => format!(
                        "{id}: registered, {} matches, {ms:.0} ms",
                        model.matches.len()
                    ),
                };
                if let Some(c) = self.current.as_mut() {
                    c.model = model.clone();
                }
                events.log(LogLevel::Info, msg);
                if self
                    .current
                    .as_ref()
                    .is_some_and(|c| c.result.image.is_none())
                {
                    events.log(LogLevel::Info, IMAGE_BRANCH_OFF);
                }
                events.send(WorkerEvent::Model(Box::new(model)));
            }
            Err(e) => {
                let msg = format!("{id}: {e}");
                if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
                    p.status = PairStatus::Failed(e.to_string());
                }
                let mut model = self.initial_model(Some(id));
                model.pairs = self.pairs.clone();
                if let Some(i) = model.current_pair {
                    model.pairs[i].status = PairStatus::Failed(e.to_string());
                }
                model.stages = vec![StageInfo {
                    name: "load + register".into(),
                    state: StageState::Failed(e.to_string()),
                    time_ms: Some(t.elapsed().as_secs_f64() * 1e3),
                }];
                self.current = None;
                events.send(WorkerEvent::Model(Box::new(model)));
                events.log(LogLevel::Error, msg);
            }
        }
    }
}

impl Worker for PipelineWorker {
    fn handle(&mut self, command: Command, events: &EventSink) {
        match command {
            Command::SelectPair(id) => self.run_and_report(&id, events),
            Command::ApplySettings(s) => {
                let image_changed = s.prompt() != self.settings.prompt()
                    || s.k != self.settings.k
                    || s.margin != self.settings.margin
                    || s.vfm != self.settings.vfm;
                self.settings = s;
                if image_changed {
                    events.log(LogLevel::Warn, IMAGE_BRANCH_OFF);
                }
                match self.current.as_ref().map(|c| c.result.pair_id.clone()) {
                    Some(id) => self.run_and_report(&id, events),
                    None => events.log(LogLevel::Info, "settings stored; no pair selected yet"),
                }
            }
            Command::InspectSourcePoint(i) => match self.inspect_point(i) {
                Ok(m) => events.send(WorkerEvent::Model(Box::new(m))),
                Err(e) => events.log(LogLevel::Warn, format!("posterior of point {i}: {e}")),
            },
            Command::Open { kind, paths } => {
                let manifest = paths.first().cloned().unwrap_or_else(PathBuf::new);
                let is_manifest = matches!(kind, super::OpenKind::Manifest | super::OpenKind::Auto)
                    && paths.len() == 1
                    && manifest
                        .extension()
                        .is_some_and(|e| e == "toml" || e == "json" || e == "txt");
                if !is_manifest {
                    events.log(
                        LogLevel::Error,
                        format!(
                            "opening {} is not supported by this worker yet; open a dataset manifest (.toml) or use `cgenreg inspect --manifest`",
                            kind.label()
                        ),
                    );
                    return;
                }
                match Dataset::load(&manifest) {
                    Ok(d) => {
                        let base = self.base.clone();
                        let settings = self.settings.clone();
                        *self = Self::new(d, base);
                        self.settings = settings;
                        events.log(
                            LogLevel::Info,
                            format!("opened {} ({} pairs)", manifest.display(), self.pairs.len()),
                        );
                        match self.pairs.first().map(|p| p.id.clone()) {
                            Some(id) => self.run_and_report(&id, events),
                            None => events.log(LogLevel::Warn, "the manifest lists no pairs"),
                        }
                    }
                    Err(e) => events.log(LogLevel::Error, format!("{}: {e}", manifest.display())),
                }
            }
            Command::RunGenerator { prompt } => events.log(
                LogLevel::Warn,
                format!("cannot generate views for “{prompt}”: {IMAGE_BRANCH_OFF}"),
            ),
            Command::Cancel => events.log(
                LogLevel::Info,
                "cancel: registrations run to completion (nothing queued was dropped)",
            ),
        }
    }
}
