//! The plain-data model the inspector draws every frame. The pipeline worker
//! ([`crate::app::worker::PipelineWorker`]) fills it; the UI never computes
//! registration results itself.
//!
//! Conventions: every cloud is in its own scan frame; `target_from_source` maps source
//! points into the target frame (p_target = T * p_source). Pixel coordinates are in the
//! pixels of the view image they belong to, origin top-left, x right, y down.

use nalgebra::Isometry3;

use crate::camera::CameraModel;

mod compare;
mod hypotheses;
mod pair_entry;

pub use compare::{CompareEvent, SettingsCompareRequest, SettingsRuns, Side};
pub use hypotheses::{HypothesisList, HypothesisRow};
pub use pair_entry::{PairOutcome, RmseReference};

/// State of one scan pair in the pair browser.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum PairStatus {
    #[default]
    Pending,
    Running,
    Done,
    /// The pair could not be registered (an error, not a failed registration).
    Failed(String),
}

/// One row of the pair browser.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PairEntry {
    pub id: String,
    pub status: PairStatus,
    /// Relative rotation error, degrees (None until estimated and GT known).
    pub rre_deg: Option<f64>,
    /// Relative translation error, metres.
    pub rte_m: Option<f64>,
    /// The manifest's split ("3DMatch", "3DLoMatch", ...; empty when it gives none).
    pub split: String,
    /// Success under the run's criterion (`RegisterParams::success`: 15° / 30 cm indoor, 5° / 2 m
    /// outdoor); None without GT.
    pub success: Option<bool>,
    /// Fraction of the correspondences within the run's inlier threshold under GT.
    pub inlier_ratio: Option<f64>,
    /// Number of selected correspondences.
    pub correspondences: Option<usize>,
    /// Registration time of the last run (ms; stages served by the cache count as loaded).
    pub time_ms: Option<f64>,
    /// The settings the row was computed with (None: not run yet).
    pub settings: Option<SettingsTag>,
    /// The scene the manifest names for it (per-scene summary rows; None: it names none).
    pub scene: Option<String>,
    /// What the official 3DMatch recall needs of a pair it counts (a gt.info entry of
    /// fragments that are not consecutive); None: the recall does not count the pair.
    pub rmse_ref: Option<Box<RmseReference>>,
    /// The RMSE of the estimate under [`crate::metrics::rmse_3dmatch`] (m), for a pair the
    /// official recall counts that was registered.
    pub rmse_m: Option<f64>,
    /// The criterion `success` was judged by, and the run's second one with its verdict.
    pub criterion: Option<crate::metrics::SuccessCriterion>,
    pub also: Option<crate::metrics::Judged>,
}

/// Which settings produced a result: a short id (blake3 of the parameters' canonical JSON) and
/// what a person reads. Rows, plot points and summaries compare ids, never labels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SettingsTag {
    pub id: String,
    pub summary: String,
}

impl SettingsTag {
    pub fn of(p: &crate::pipeline::RegisterParams) -> Self {
        let json = serde_json::to_vec(p).unwrap_or_default();
        let id = blake3::hash(&json).to_hex()[..8].to_string();
        Self {
            summary: settings_summary(p),
            id,
        }
    }
}

/// One line naming the settings that change a result: the branches and their main parameters.
pub fn settings_summary(p: &crate::pipeline::RegisterParams) -> String {
    let features = match p.geo_features {
        crate::pipeline::params::GeoFeatureSource::Fpfh => "FPFH",
        _ => "learned features",
    };
    let geo = format!("{features} v = {} cm", fmt_num(p.voxel * 100.0));
    let fusion = &p.fusion;
    match &p.image {
        None => format!(
            "geometry only ({geo}), {}, {}",
            fusion.selection.label(),
            p.estimator.label()
        ),
        Some(ib) => format!(
            "{} + {} (L = {}, m = {}, K = {}), {geo}, {}, {}, {}",
            ib.backend.label(),
            ib.vfm.label(),
            ib.frames_per_fragment,
            ib.margin,
            ib.k,
            fusion.mode.label(),
            fusion.selection.label(),
            p.estimator.label()
        ),
    }
}

fn fmt_num(x: f64) -> String {
    let s = format!("{x:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

impl PairEntry {
    /// A row not run yet.
    pub fn pending(id: impl Into<String>, split: impl Into<String>) -> Self {
        Self {
            id: id.into(),
            split: split.into(),
            ..Default::default()
        }
    }

    pub fn outcome(&self) -> PairOutcome {
        match (&self.status, self.success) {
            (PairStatus::Pending, _) => PairOutcome::Pending,
            (PairStatus::Running, _) => PairOutcome::Running,
            (PairStatus::Failed(_), _) => PairOutcome::Error,
            (PairStatus::Done, Some(true)) => PairOutcome::Success,
            (PairStatus::Done, Some(false)) => PairOutcome::Failure,
            (PairStatus::Done, None) => PairOutcome::Done,
        }
    }

    /// Clears the metrics of a previous run (the row becomes `status`).
    pub fn reset(&mut self, status: PairStatus) {
        *self = Self {
            id: std::mem::take(&mut self.id),
            split: std::mem::take(&mut self.split),
            scene: self.scene.take(),
            rmse_ref: self.rmse_ref.take(),
            status,
            ..Default::default()
        };
    }
}

/// Which branch proposed a correspondence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Branch {
    Image,
    Geometry,
    Both,
}

impl Branch {
    pub fn label(self) -> &'static str {
        match self {
            Branch::Image => "image",
            Branch::Geometry => "geometry",
            Branch::Both => "both",
        }
    }
}

/// One putative correspondence between a source point and a target point.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchInfo {
    pub src: usize,
    pub tgt: usize,
    /// Fused confidence in [0, 1].
    pub score: f32,
    /// Inlier under the ground-truth transform (None when GT is unknown).
    pub inlier_gt: Option<bool>,
    pub branch: Branch,
    /// Whether SC2-PCR kept it in its final inlier set (None before estimation).
    pub survived: Option<bool>,
}

/// An 8-bit RGB image, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

impl RgbImage {
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            pixels: vec![0; (width * height * 3) as usize],
        }
    }
    pub fn put(&mut self, x: u32, y: u32, rgb: [u8; 3]) {
        if x < self.width && y < self.height {
            let i = ((y * self.width + x) * 3) as usize;
            self.pixels[i..i + 3].copy_from_slice(&rgb);
        }
    }
    pub fn get(&self, x: u32, y: u32) -> [u8; 3] {
        let i = ((y * self.width + x) * 3) as usize;
        [self.pixels[i], self.pixels[i + 1], self.pixels[i + 2]]
    }
}

/// Where a view came from: always shown next to the image so generated frames are never
/// mistaken for frames of another prompt.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewLabel {
    /// "cosmos", "oracle", "built-in", ...
    pub backend: String,
    pub prompt: String,
    /// Cache entry (hash or folder) the frame was read from.
    pub cache_entry: String,
}

/// The camera of a view, in the frame of the cloud it looks at.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewCamera {
    /// Camera pose: p_cloud = cloud_from_camera * p_camera (OpenCV axes).
    pub cloud_from_camera: Isometry3<f64>,
    /// Pinhole or f-theta (the LiDAR virtual camera).
    pub camera: CameraModel,
}

/// One of the K views of a scan.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewImage {
    pub label: ViewLabel,
    pub rgb: RgbImage,
    /// The depth frame the view was generated from, already colour-mapped for display.
    pub depth: Option<RgbImage>,
    pub camera: Option<ViewCamera>,
    /// Per display point of this view's scan ([`InspectorModel::source`] or `target`): 0 outside
    /// the view, 1 inside it but occluded, 2 visible. Empty when the camera is unknown.
    pub point_state: Vec<u8>,
    /// Per correspondence (index into `InspectorModel::matches`): the pixel of this scan's
    /// endpoint in this view, when it is visible.
    pub match_pixels: Vec<Option<[f32; 2]>>,
}

/// Branch posteriors of one source point over candidate target points.
#[derive(Clone, Debug, PartialEq)]
pub struct Posterior {
    pub source_point: usize,
    /// Pixel of the source point in source view `source_view`, if visible.
    pub source_pixel: Option<[f32; 2]>,
    pub source_view: usize,
    /// Candidate target point indices; the three rows below are aligned with it.
    pub candidates: Vec<usize>,
    pub image: Vec<f32>,
    pub geometric: Vec<f32>,
    pub fused: Vec<f32>,
    /// Target view the candidates are drawn on, and their pixels there.
    pub target_view: usize,
    pub candidate_pixels: Vec<Option<[f32; 2]>>,
    /// Ground-truth target point (nearest target point to T_gt * source point).
    pub gt_target: Option<usize>,
    /// Whether this point's selected match survived SC2-PCR.
    pub survived: Option<bool>,
    /// Why this point is shown ("chosen by click", or why the tab opened on it).
    pub reason: String,
}

/// State of one pipeline stage.
#[derive(Clone, Debug, PartialEq)]
pub enum StageState {
    Cached,
    Stale,
    Running,
    Failed(String),
    Done,
}

/// Where a stage row's time sits: the total adds top-level rows only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StageRole {
    /// A step timed on its own (e.g. comparing the stage keys after a settings change).
    #[default]
    Stage,
    /// A row whose time includes the [`StageRole::Part`] rows ("load + register",
    /// "re-fuse from memory").
    Container,
    /// A pipeline stage timed inside a container row.
    Part,
}

#[derive(Clone, Debug, PartialEq)]
pub struct StageInfo {
    pub name: String,
    /// The pipeline stage the row times (None: the worker's own rows, e.g. "load + register",
    /// "re-fuse from memory", the settings change's key comparison).
    pub stage: Option<crate::pipeline::plan::StageName>,
    pub state: StageState,
    pub time_ms: Option<f64>,
    /// Whether the total adds it (see [`StageRole`]).
    pub role: StageRole,
}

/// Precision-recall curve of the matches, points are (recall, precision).
#[derive(Clone, Debug, PartialEq)]
pub struct PrCurve {
    pub name: String,
    pub points: Vec<[f64; 2]>,
}

/// Mean RRE/RTE at one K over the pairs that ran (figure 6).
#[derive(Clone, Debug, PartialEq)]
pub struct KPoint {
    pub k: usize,
    pub rre_deg: f64,
    pub rte_m: f64,
    /// Pairs that entered the means.
    pub pairs: usize,
    /// Pairs left out (generation not available, no ground truth) or failed.
    pub skipped: usize,
    /// Registration recall (RRE <= 15 deg, RTE <= 30 cm) over the pairs run or failed.
    pub recall: Option<f64>,
}

/// Mean RRE/RTE per prompt category (figure 4).
#[derive(Clone, Debug, PartialEq)]
pub struct PromptBar {
    pub category: String,
    pub rre_deg: f64,
    pub rte_m: f64,
    /// Pairs with generations for this prompt that entered the mean.
    pub pairs: usize,
    /// Pairs left out (generation not available, no ground truth) or failed.
    pub skipped: usize,
    pub recall: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlotData {
    pub pr_curves: Vec<PrCurve>,
    pub vs_k: Vec<KPoint>,
    pub prompt_study: Vec<PromptBar>,
    /// What produced `vs_k` / `prompt_study`: backend ids, VFM, fusion and pair counts.
    pub vs_k_source: String,
    pub prompt_source: String,
    /// A study running on the worker: (what, runs done, runs in all).
    pub study_progress: Option<(String, usize, usize)>,
    /// Both figure-7 curves can be computed (image branch + ground truth) but are not in
    /// `pr_curves` yet: the plots panel asks the worker for them when it is shown.
    pub figure7_pending: bool,
}

/// Everything the inspector shows. Plain data, cheap to read every frame.
#[derive(Clone, Debug, PartialEq)]
pub struct InspectorModel {
    pub pairs: Vec<PairEntry>,
    /// Index into `pairs` of the pair shown.
    pub current_pair: Option<usize>,
    pub source: Vec<[f32; 3]>,
    pub target: Vec<[f32; 3]>,
    pub initial: Isometry3<f64>,
    pub estimated: Option<Isometry3<f64>>,
    pub ground_truth: Option<Isometry3<f64>>,
    pub matches: Vec<MatchInfo>,
    /// The distance (m) under which a match is a GT inlier: the run's inlier threshold (0.10 m
    /// indoor, 0.6 m outdoor), what `matches[i].inlier_gt` was judged by.
    pub gt_inlier_m: f64,
    pub source_views: Vec<ViewImage>,
    pub target_views: Vec<ViewImage>,
    pub posteriors: Vec<Posterior>,
    /// The source point the posterior tab opens on (see `worker::default_posterior_point`).
    pub default_posterior: Option<usize>,
    pub stages: Vec<StageInfo>,
    pub plots: PlotData,
    /// A changed prompt whose generation is not cached: the UI offers to run the generator.
    pub generation_missing: Option<String>,
    /// Why no views are shown (image branch off, or not available for this pair/build).
    pub image_branch_note: Option<String>,
    /// The inverse of the ground truth explains the data better than the ground truth
    /// (`metrics::convention`): shown next to the metrics.
    pub convention_warning: Option<String>,
    /// What the `union` fusion merged and where its inliers came from ("fusion: union (...)"):
    /// shown next to the metrics.
    pub fusion_note: Option<String>,
    /// The estimator's ranked hypotheses (computed on demand by the hypothesis browser).
    pub hypotheses: Option<HypothesisList>,
    /// How the shown result is judged: its criterion and the run's second one, with the outcome
    /// under each ("success (RRE ≤ 5°, RTE ≤ 2 m); also RRE ≤ 5°, RTE ≤ 0.6 m: fails").
    pub criteria_note: Option<String>,
    /// A scale search's hypotheses (voxel, V, the one kept): shown beside the metrics and in the
    /// Hypotheses tab.
    pub scale_note: Option<String>,
    /// Set on a fast answer shown while the settings' own result is computed (a temperature
    /// change under the visibility rule): what it is; the refined model clears it.
    pub preview_note: Option<String>,
    /// What actually ran for the shown result ("geometry (FPFH) + image (oracle, XFeat)"):
    /// the pair's header shows it next to the settings asked for.
    pub branches_ran: Option<String>,
    /// The settings the shown result was computed with.
    pub settings: Option<SettingsTag>,
    /// Set while the bundled demo runs under its own protocol (what it is, for the controls).
    pub demo_protocol: Option<String>,
    /// The open data set's own scene description (its manifest's `scene_prompt`): what the
    /// "Scene-specific" prompt button puts in the editor. None: the pipeline's text.
    pub scene_prompt: Option<String>,
}

impl Default for InspectorModel {
    fn default() -> Self {
        Self {
            pairs: Vec::new(),
            current_pair: None,
            source: Vec::new(),
            target: Vec::new(),
            initial: Isometry3::identity(),
            estimated: None,
            ground_truth: None,
            matches: Vec::new(),
            gt_inlier_m: crate::pipeline::RegisterParams::default().inlier_threshold_m(),
            source_views: Vec::new(),
            target_views: Vec::new(),
            posteriors: Vec::new(),
            default_posterior: None,
            stages: Vec::new(),
            plots: PlotData::default(),
            generation_missing: None,
            image_branch_note: None,
            convention_warning: None,
            fusion_note: None,
            hypotheses: None,
            criteria_note: None,
            scale_note: None,
            preview_note: None,
            branches_ran: None,
            settings: None,
            demo_protocol: None,
            scene_prompt: None,
        }
    }
}

impl InspectorModel {
    /// Small synthetic UI fixture (about 6k points per cloud) exercising every panel in tests and
    /// benchmarks. Its views are labelled as fixture renders and its extra pairs carry made-up
    /// metrics by design; the inspector itself always shows pipeline results.
    pub fn demo() -> Self {
        Self::demo_sized(6000)
    }

    /// The synthetic demo with `n` points per cloud (benchmarks use 100k and 300k).
    pub fn demo_sized(n: usize) -> Self {
        demo::build(n)
    }

    /// [`Self::gt_inlier_m`] as people read it: "10 cm", "60 cm", "2.4 m".
    pub fn gt_inlier_label(&self) -> String {
        distance_label(self.gt_inlier_m)
    }

    /// Each match's rank quantile of fused score in [0, 1] (the confidence colours).
    pub fn score_quantiles(&self) -> Vec<f32> {
        let s: Vec<f32> = self.matches.iter().map(|m| m.score).collect();
        super::colormap::rank_quantiles(&s)
    }

    /// Posterior for a source point, if the pipeline computed one.
    pub fn posterior_for(&self, source_point: usize) -> Option<&Posterior> {
        self.posteriors
            .iter()
            .find(|p| p.source_point == source_point)
    }

    /// Axis-aligned bounds of both clouds (target frame for the target, source frame for the
    /// source), used to frame the camera.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        bounds_of(self.source.iter().chain(self.target.iter()))
    }
}

/// Axis-aligned bounds (min, max) of some points; None for none.
pub fn bounds_of<'a>(pts: impl IntoIterator<Item = &'a [f32; 3]>) -> Option<([f32; 3], [f32; 3])> {
    let mut it = pts.into_iter();
    let first = *it.next()?;
    let (mut lo, mut hi) = (first, first);
    for p in it {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    Some((lo, hi))
}

/// RRE (degrees) and RTE (metres) of `estimated` against `gt`, by the metrics module.
pub fn pose_errors(gt: &Isometry3<f64>, estimated: &Isometry3<f64>) -> (f64, f64) {
    (
        crate::metrics::rre_deg(estimated, gt),
        crate::metrics::rte_m(estimated, gt),
    )
}

mod demo;

/// A distance in metres as people read it: centimetres under a metre ("10 cm"), else metres
/// ("2.4 m").
pub fn distance_label(m: f64) -> String {
    if m < 1.0 {
        format!("{} cm", (m * 100.0 * 10.0).round() / 10.0)
    } else {
        format!("{} m", (m * 100.0).round() / 100.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn demo_is_consistent() {
        let m = InspectorModel::demo();
        assert_eq!(m.source.len(), 6000);
        assert_eq!(m.target.len(), 6000);
        assert!(m.matches.len() > 100);
        let gt = m.ground_truth.unwrap();
        // inlier flags agree with the GT transform
        for c in &m.matches {
            let s = m.source[c.src];
            let t = m.target[c.tgt];
            let q = gt * Point3::new(s[0] as f64, s[1] as f64, s[2] as f64);
            let d = (q - Point3::new(t[0] as f64, t[1] as f64, t[2] as f64)).norm();
            assert_eq!(c.inlier_gt, Some(d < 0.1));
        }
        let inl = m
            .matches
            .iter()
            .filter(|c| c.inlier_gt == Some(true))
            .count();
        assert!(inl * 2 > m.matches.len(), "inlier ratio too low: {inl}");
        for v in m.source_views.iter().chain(&m.target_views) {
            assert_eq!(v.match_pixels.len(), m.matches.len());
            let visible = v.match_pixels.iter().flatten().count();
            assert!(
                visible > m.matches.len() / 4,
                "too few visible endpoints: {visible}"
            );
        }
        // The library's posteriors: row softmaxes sum to 1, the Noisy-AND fusion lies in
        // [0, 1] and ranks the candidates as the product of the branch odds does.
        assert_eq!(m.posteriors.len(), 12);
        for p in &m.posteriors {
            assert_eq!(p.candidates.len(), 300);
            for row in [&p.image, &p.geometric] {
                let s: f32 = row.iter().sum();
                assert!((s - 1.0).abs() < 1e-3);
            }
            assert!(p.fused.iter().all(|f| (0.0..=1.0).contains(f)));
            let odds = |j: usize| {
                let (a, b) = (p.image[j] as f64, p.geometric[j] as f64);
                a * b / ((1.0 - a) * (1.0 - b))
            };
            let best = (0..300)
                .max_by(|&i, &j| odds(i).total_cmp(&odds(j)))
                .unwrap();
            let top = (0..300)
                .max_by(|&i, &j| p.fused[i].total_cmp(&p.fused[j]))
                .unwrap();
            assert!(p.fused[top] == p.fused[best], "{top} vs {best}");
        }
        let (rre, rte) = pose_errors(&gt, m.estimated.as_ref().unwrap());
        assert!(rre > 0.1 && rre < 3.0 && rte < 0.1);
    }
}
