//! The inspector's pipeline worker: owns a dataset, registers the selected pair with the UI's
//! settings on the worker thread (the image branch through the stage cache when a WFM is
//! chosen), and turns the result into an [`InspectorModel`].
//!
//! What is kept in memory per pair: the geometric branch (keypoints + FPFH) and, after a run
//! with the image branch, every input of the in-memory stages ([`FusionInputs`]) and the
//! selected views. A change of temperature, calibration, fusion mode, selection or estimator
//! then re-runs only similarity, fusion and estimation ([`fuse_and_finish`]); a change of
//! prompt, seed, K, margin, VFM or backend re-runs the cached pipeline.
//!
//! Model conventions: `model.source` / `model.target` start with the registration keypoints
//! (so `MatchInfo::src` / `tgt` are keypoint indices), followed by a strided subsample of the
//! full scan for display. Clouds stay in their own scan frames; `estimated` and
//! `ground_truth` are target_from_source.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Isometry3, Point3};

use super::controls::{Command, EventSink, LogLevel, StudyRequest, Worker, WorkerEvent};
use super::model::{
    Branch, InspectorModel, MatchInfo, PairEntry, PairStatus, PlotData, Posterior, PrCurve,
    RgbImage, StageInfo, StageState, ViewCamera, ViewImage, ViewLabel,
};
use crate::dataset::manifest::Dataset;
use crate::dataset::ScanPair;
use crate::fusion::fuse::FusionMode;
use crate::pipeline::cache::Cache;
use crate::pipeline::fuse::{fuse_and_finish, similarities, FusionInputs, Similarities};
use crate::pipeline::geo::{fpfh_branch, GeoBranch};
use crate::pipeline::image_branch::register_with_image_keep;
use crate::pipeline::study::{
    k_settings, prompt_settings, run_study_with, StudyReport, StudySetting,
};
use crate::pipeline::{
    ImageBranchOutput, ImageBranchParams, RegisterParams, RegistrationResult, WfmSpec,
};

/// Inlier threshold of the GT flags on correspondences (metres).
pub const GT_INLIER_M: f64 = 0.10;
/// A match is correct within this distance under the ground truth in the paper's figure 7.
pub const FIGURE7_CORRECT_M: f64 = 0.05;
/// Display points per cloud on top of the keypoints.
pub const DISPLAY_POINTS: usize = 150_000;
/// Candidates kept per posterior.
const POSTERIOR_CANDIDATES: usize = 400;

/// Why the image branch is not shown when no WFM is chosen.
pub const IMAGE_BRANCH_OFF: &str = "image branch off (WFM: none) — the geometric branch ran \
alone, so there are no views to show and the fused posterior equals the geometric one; choose \
a WFM under “Image branch” (oracle needs a pair with RGB-D frames)";

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

/// The depth frame of a view as the WFM saw it (the depth video's grey inverse depth) and, per
/// display point of its scan, 0 outside the view, 1 occluded, 2 visible. Memoised: a re-fusion
/// (temperature, fusion mode) shows the same views and must not redo this.
type ViewExtras = Arc<(RgbImage, Vec<u8>)>;
fn view_depth_and_visibility(
    depth_path: &std::path::Path,
    cam: &ViewCamera,
    cloud: &[[f32; 3]],
    cloud_key: &blake3::Hash,
) -> Option<ViewExtras> {
    static MEMO: std::sync::OnceLock<std::sync::Mutex<Vec<(blake3::Hash, ViewExtras)>>> =
        std::sync::OnceLock::new();
    let mut h = blake3::Hasher::new();
    h.update(depth_path.as_os_str().as_encoded_bytes());
    for x in cam.cloud_from_camera.to_homogeneous().iter() {
        h.update(&x.to_le_bytes());
    }
    h.update(format!("{:?}", cam.camera).as_bytes());
    h.update(cloud_key.as_bytes());
    let key = h.finalize();
    let memo = MEMO.get_or_init(Default::default);
    if let Some(hit) = memo
        .lock()
        .ok()?
        .iter()
        .find(|(k, _)| *k == key)
        .map(|(_, v)| v.clone())
    {
        return Some(hit);
    }
    // A missing or unreadable depth frame leaves the view without its depth toggle; the
    // pipeline already read the same file, so this is not expected.
    let d = crate::io::depth_png::read_depth_png(depth_path).ok()?;
    let g =
        crate::wfm::depth_video::gray_to_rgb(&crate::wfm::depth_video::encode_depth_frame_clip(
            &d,
            crate::pipeline::image_branch::depth_video_clip(&cam.camera),
        ));
    let pts: Vec<Point3<f32>> = cloud
        .iter()
        .map(|p| Point3::new(p[0], p[1], p[2]))
        .collect();
    let camera_from_cloud = cam.cloud_from_camera.inverse();
    let visible = cam.camera.visibility(&pts, &camera_from_cloud);
    let (w, h) = cam.camera.size();
    let state = pts
        .iter()
        .zip(&visible)
        .map(|(p, &vis)| {
            if vis {
                return 2;
            }
            let inside = cam
                .camera
                .project(&(camera_from_cloud * p.cast::<f64>()))
                .is_some_and(|(u, v)| {
                    u >= -0.5 && v >= -0.5 && u < w as f64 - 0.5 && v < h as f64 - 0.5
                });
            // Behind a pinhole camera nothing projects; in front and inside but not seen: occluded.
            u8::from(inside)
        })
        .collect();
    let out: ViewExtras = Arc::new((
        RgbImage {
            width: g.width(),
            height: g.height(),
            pixels: g.into_raw(),
        },
        state,
    ));
    if let Ok(mut m) = memo.lock() {
        if m.len() >= 16 {
            m.remove(0);
        }
        m.push((key, out.clone()));
    }
    Some(out)
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

    // One content hash per display cloud keys the views' visibility memo (hashed as one
    // buffer: per-value updates cost more than the fusion they follow).
    let cloud_key = |c: &[[f32; 3]]| {
        let bytes: Vec<u8> = c
            .iter()
            .flat_map(|p| p.iter().flat_map(|x| x.to_le_bytes()))
            .collect();
        blake3::hash(&bytes)
    };
    let (source_key, target_key) = (cloud_key(&source), cloud_key(&target));
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
                        // `v.label` is "backend | prompt | cache <hash>": keep the cache part
                        let entry = v
                            .label
                            .rsplit(" | ")
                            .next()
                            .filter(|e| e.starts_with("cache"))
                            .unwrap_or(v.label.as_str());
                        let cam = v.scan_from_camera.map(|pose| ViewCamera {
                            cloud_from_camera: pose,
                            camera: v.camera.clone(),
                        });
                        let (cloud, cloud_key) = if is_src {
                            (&source, &source_key)
                        } else {
                            (&target, &target_key)
                        };
                        let shown = v
                            .depth_path
                            .as_deref()
                            .zip(cam.as_ref())
                            .and_then(|(p, c)| view_depth_and_visibility(p, c, cloud, cloud_key));
                        ViewImage {
                            label: ViewLabel {
                                backend: prov.model.clone(),
                                prompt: prov.prompt.clone(),
                                cache_entry: format!(
                                    "{entry} · generated frame {} · depth frame {} ({})",
                                    v.generated_index,
                                    v.depth_index,
                                    v.camera.name()
                                ),
                            },
                            rgb: RgbImage {
                                width: v.image.width(),
                                height: v.image.height(),
                                pixels: v.image.as_raw().clone(),
                            },
                            depth: shown.as_ref().map(|d| d.0.clone()),
                            camera: cam,
                            point_state: shown.map(|d| d.1.clone()).unwrap_or_default(),
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
        ..Default::default()
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
        default_posterior: None,
        stages,
        plots,
        generation_missing: None,
        image_branch_note: note,
        convention_warning: result.convention.as_ref().and_then(|c| c.warning.clone()),
        hypotheses: None,
    }
}

fn top_indices(v: &[f32], n: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    let n = n.min(idx.len());
    if n == 0 {
        return Vec::new();
    }
    idx.select_nth_unstable_by(n - 1, |&a, &b| v[b].total_cmp(&v[a]));
    idx.truncate(n);
    idx.sort_by(|&a, &b| v[b].total_cmp(&v[a]));
    idx
}

/// Branch posteriors of source keypoint `src` over the target keypoints: row `src` of the
/// posteriors `match_then_fuse` forms from the kept similarities `sims` with `fusion`
/// ([`crate::fusion::posterior_row`]; without the image branch the mode is geometry only).
/// Points without a pixel have an image posterior of 0, as in the pipeline. Candidates: the
/// most likely under the fused, image and geometric posteriors, plus the ground-truth target.
pub fn point_posterior(
    inputs: &FusionInputs,
    sims: &Similarities,
    image: Option<&ImageBranchOutput>,
    fusion: &crate::fusion::FusionParams,
    src: usize,
    gt: Option<&Isometry3<f64>>,
    survived: Option<bool>,
) -> crate::Result<Posterior> {
    let (sg, tg) = (&inputs.source_geo, &inputs.target_geo);
    let mut fusion = *fusion;
    if sims.image.is_none() {
        fusion.mode = FusionMode::GeometryOnly;
    }
    let row = crate::fusion::posterior_row(
        sims.image
            .as_ref()
            .map(|(s, rv, cv)| (s, Some(rv.as_slice()), Some(cv.as_slice()))),
        Some(&sims.geo),
        &fusion,
        src,
    )?;
    let p_geo = row.geometric.unwrap_or_default();
    let p_img = row.image;
    let fused = row.fused;
    let gt_target = gt.map(|g| {
        let q = g * sg.keypoints.points[src].cast::<f64>();
        let mut best = (0, f64::INFINITY);
        for (j, t) in tg.keypoints.points.iter().enumerate() {
            let d = (t.cast::<f64>() - q).norm_squared();
            if d < best.1 {
                best = (j, d);
            }
        }
        best.0
    });
    let mut candidates = top_indices(&fused, POSTERIOR_CANDIDATES);
    let mut seen: std::collections::HashSet<usize> = candidates.iter().copied().collect();
    let extra = POSTERIOR_CANDIDATES / 4;
    let mut more = top_indices(&p_geo, extra);
    if let Some(pi) = &p_img {
        more.extend(top_indices(pi, extra));
    }
    more.extend(gt_target);
    for j in more {
        if seen.insert(j) {
            candidates.push(j);
        }
    }
    let link =
        |links: &[Option<crate::vfm::lift::PixelLink>], j: usize| links.get(j).copied().flatten();
    let (source_view, source_pixel) = match image.and_then(|o| link(&o.source_links, src)) {
        Some(l) => (l.view as usize, Some([l.u as f32, l.v as f32])),
        None => (0, None),
    };
    // the target view of the ground-truth point, else of the most likely candidate
    let target_view = image
        .and_then(|o| {
            gt_target
                .into_iter()
                .chain(candidates.first().copied())
                .find_map(|j| link(&o.target_links, j))
        })
        .map_or(0, |l| l.view as usize);
    let candidate_pixels = candidates
        .iter()
        .map(|&j| {
            image
                .and_then(|o| link(&o.target_links, j))
                .filter(|l| l.view as usize == target_view)
                .map(|l| [l.u as f32, l.v as f32])
        })
        .collect();
    let pick = |v: &[f32]| candidates.iter().map(|&j| v[j]).collect::<Vec<f32>>();
    Ok(Posterior {
        source_point: src,
        source_pixel,
        source_view,
        image: p_img.as_ref().map(|p| pick(p)).unwrap_or_default(),
        geometric: pick(&p_geo),
        fused: pick(&fused),
        candidates,
        candidate_pixels,
        target_view,
        gt_target,
        survived,
        reason: String::new(),
    })
}

/// The source point the posterior tab opens on after a run, and why: the strongest selected
/// match that fails under the ground truth (its target more than 10 cm from where the GT
/// puts the source point), else the strongest match. None without matches.
pub fn default_posterior_point(matches: &[MatchInfo]) -> Option<(usize, String)> {
    let strongest = |keep: &dyn Fn(&MatchInfo) -> bool| {
        matches
            .iter()
            .enumerate()
            .filter(|(_, m)| keep(m))
            .max_by(|(i, a), (j, b)| a.score.total_cmp(&b.score).then(j.cmp(i)))
    };
    let rank = |m: &MatchInfo| 1 + matches.iter().filter(|o| o.score > m.score).count();
    let n = matches.len();
    if let Some((_, m)) = strongest(&|m| m.inlier_gt == Some(false)) {
        let wrong = matches
            .iter()
            .filter(|m| m.inlier_gt == Some(false))
            .count();
        return Some((
            m.src,
            format!(
                "opened on the strongest selected match that fails under GT: source #{} -> target #{}, \
                 fused score {:.3} (rank {} of {n}; {wrong} of {n} matches are > 10 cm off GT)",
                m.src,
                m.tgt,
                m.score,
                rank(m)
            ),
        ));
    }
    let (_, m) = strongest(&|_| true)?;
    let why = if matches.iter().any(|m| m.inlier_gt.is_some()) {
        "every selected match is within 10 cm of GT"
    } else {
        "no ground truth for this pair"
    };
    Some((
        m.src,
        format!(
            "opened on the strongest selected match ({why}): source #{} -> target #{}, fused \
             score {:.3}",
            m.src, m.tgt, m.score
        ),
    ))
}

/// What a run left in memory for fast re-runs of the stages after it.
struct Kept {
    /// The settings that produced `inputs` (image branch, voxel, features), as JSON.
    signature: String,
    inputs: Arc<FusionInputs>,
    /// Both similarity matrices (about 2 x 200 MB at 7k keypoints, for the current pair only):
    /// a temperature change then costs fusion + estimate only.
    sims: Option<Arc<Similarities>>,
    image: Option<ImageBranchOutput>,
    /// Stages of that run (shown as cached when only fusion onward re-runs).
    stages: Vec<StageInfo>,
    note: Option<String>,
    generation_missing: Option<String>,
}

/// A pair loaded and registered, kept for re-runs and posterior requests.
struct Current {
    pair: ScanPair,
    result: RegistrationResult,
    model: InspectorModel,
    kept: Option<Kept>,
}

fn signature(p: &RegisterParams) -> String {
    serde_json::to_string(&(p.voxel, &p.geo_features, &p.image)).unwrap_or_default()
}

/// The [`Worker`] behind `cgenreg inspect`.
pub struct PipelineWorker {
    dataset: Dataset,
    /// The parameters in force: the command line's at start, then the controls'.
    params: RegisterParams,
    pairs: Vec<PairEntry>,
    current: Option<Current>,
    /// Loaded pairs by id (loading a fragment is the slowest step for real scans).
    loaded: HashMap<String, ScanPair>,
    /// Geometric branch per (pair, voxel), so geometry-only re-runs skip FPFH.
    geo: HashMap<(String, u64), Arc<FusionInputs>>,
    /// The stage cache of the image branch (None: everything computed in memory).
    cache: Option<Arc<Cache>>,
    /// Why there is no cache, reported once.
    cache_note: Option<String>,
    /// Results of the last K sweep / prompt study on this dataset (kept in every model).
    studies: StudyPlots,
    /// Set by the UI thread (WorkerHandle::send(Command::Cancel)) to stop a running study
    /// between pairs; the worker is busy then and reads no commands.
    cancel: Arc<std::sync::atomic::AtomicBool>,
}

/// What the plots panel shows of the studies run on the open dataset.
#[derive(Clone, Debug, Default)]
struct StudyPlots {
    vs_k: Vec<super::model::KPoint>,
    vs_k_source: String,
    prompt: Vec<super::model::PromptBar>,
    prompt_source: String,
}

impl StudyPlots {
    fn fill(&self, plots: &mut PlotData) {
        plots.vs_k = self.vs_k.clone();
        plots.vs_k_source = self.vs_k_source.clone();
        plots.prompt_study = self.prompt.clone();
        plots.prompt_source = self.prompt_source.clone();
        plots.study_progress = None;
    }
}

/// The plots of a study report: one point / bar per setting that ran at least one pair.
fn study_plots(rep: &StudyReport) -> (Vec<super::model::KPoint>, Vec<super::model::PromptBar>) {
    let ran = || {
        rep.rows
            .iter()
            .filter(|r| r.setting_skipped.is_none() && r.pairs_run > 0)
    };
    let k = ran()
        .map(|r| super::model::KPoint {
            k: r.k,
            rre_deg: r.rre_mean_deg.unwrap_or(f64::NAN),
            rte_m: r.rte_mean_m.unwrap_or(f64::NAN),
            pairs: r.pairs_run,
            skipped: r.skipped.len() + r.failed.len(),
            recall: r.recall,
        })
        .collect();
    let p = ran()
        .map(|r| super::model::PromptBar {
            category: r.setting.clone(),
            rre_deg: r.rre_mean_deg.unwrap_or(f64::NAN),
            rte_m: r.rte_mean_m.unwrap_or(f64::NAN),
            pairs: r.pairs_run,
            skipped: r.skipped.len() + r.failed.len(),
            recall: r.recall,
        })
        .collect();
    (k, p)
}

impl PipelineWorker {
    /// A worker on `dataset` with the default stage cache (`$CGENREG_CACHE` or
    /// `~/.cache/cgenreg`).
    pub fn new(dataset: Dataset, base: RegisterParams) -> Self {
        let dir = crate::pipeline::image_branch::default_cache_dir();
        let (cache, cache_note) = match Cache::open(&dir) {
            Ok(c) => (Some(Arc::new(c)), None),
            Err(e) => (
                None,
                Some(format!(
                    "stage cache {} unavailable ({e}); the image branch computes every stage in memory",
                    dir.display()
                )),
            ),
        };
        Self::with_cache(dataset, base, cache, cache_note)
    }

    fn with_cache(
        dataset: Dataset,
        base: RegisterParams,
        cache: Option<Arc<Cache>>,
        cache_note: Option<String>,
    ) -> Self {
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
        let mut params = base;
        if params.image.is_none() {
            // without the image branch only geometry-only fusion runs: show what ran
            params.fusion.mode = FusionMode::GeometryOnly;
        }
        Self {
            dataset,
            params,
            pairs,
            current: None,
            loaded: HashMap::new(),
            geo: HashMap::new(),
            cache,
            cache_note,
            studies: StudyPlots::default(),
            cancel: Arc::default(),
        }
    }

    /// Replaces the stage cache (None: compute every stage in memory, `--no-cache`).
    pub fn set_cache(&mut self, cache: Option<Cache>) {
        self.cache_note = None;
        self.cache = cache.map(Arc::new);
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
            image_branch_note: Some(if self.params.image.is_some() {
                "registering…".to_string()
            } else {
                IMAGE_BRANCH_OFF.to_string()
            }),
            ..Default::default()
        }
    }

    /// Records a pair that could not be registered (shown as failed in the browser).
    pub fn mark_failed(&mut self, id: &str, why: &str) {
        if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
            p.status = PairStatus::Failed(why.to_string());
        }
    }

    /// The parameters in force (what the controls show).
    pub fn params(&self) -> &RegisterParams {
        &self.params
    }

    /// Replaces the parameters without running anything (the next run uses them).
    pub fn set_params(&mut self, p: RegisterParams) {
        self.params = p;
    }

    /// Loads (or reuses) and registers one pair, generating views when needed; returns the
    /// model. Synchronous.
    pub fn run_pair(&mut self, id: &str) -> crate::Result<InspectorModel> {
        self.run_pair_with(id, true)
    }

    /// The geometric branch of `pair` from memory, or computed (FPFH) and kept.
    fn geometry(
        &mut self,
        id: &str,
        pair: &ScanPair,
        voxel: f64,
    ) -> crate::Result<(Arc<FusionInputs>, Vec<crate::pipeline::StageTiming>)> {
        let key = (id.to_string(), voxel.to_bits());
        if let Some(g) = self.geo.get(&key) {
            let t = crate::pipeline::StageTiming {
                stage: "fpfh source + target (in memory)".into(),
                ms: 0.0,
                status: "cached".into(),
            };
            return Ok((g.clone(), vec![t]));
        }
        let mut timings = Vec::new();
        let mut branch = |name: &str, cloud| -> crate::Result<GeoBranch> {
            let t = Instant::now();
            let b = fpfh_branch(cloud, voxel)?;
            timings.push(crate::pipeline::StageTiming {
                stage: name.into(),
                ms: t.elapsed().as_secs_f64() * 1e3,
                status: "computed".into(),
            });
            Ok(b)
        };
        let s = branch("fpfh source", &pair.source.cloud)?;
        let t = branch("fpfh target", &pair.target.cloud)?;
        let g = Arc::new(FusionInputs {
            source_geo: s,
            target_geo: t,
            image: None,
            image_label: None,
        });
        self.geo.insert(key, g.clone());
        Ok((g, timings))
    }

    /// [`run_pair`](Self::run_pair); with `generate` false a generation missing from the cache
    /// is not produced: the model says so (`generation_missing`) and shows no views.
    pub fn run_pair_with(&mut self, id: &str, generate: bool) -> crate::Result<InspectorModel> {
        let pair = match self.loaded.get(id) {
            Some(p) => p.clone(),
            None => {
                let p = self.dataset.load_pair(id)?;
                self.loaded.insert(id.to_string(), p.clone());
                p
            }
        };
        let params = self.params.clone();
        let sig = signature(&params);
        let mut note: Option<String> = None;
        let mut missing: Option<String> = None;
        let mut with_image: Option<(RegistrationResult, FusionInputs)> = None;
        if let Some(ib) = &params.image {
            if let Some(n) = self.cache_note.take() {
                note = Some(n);
            }
            let cache = self.cache.clone();
            // A panic here reaches the worker thread's guard (`spawn_worker`), which reports it.
            match register_with_image_keep(&pair, &params, ib, cache.as_deref(), generate) {
                Ok(x) => with_image = Some(x),
                Err(e @ crate::Error::GenerationNotCached { .. }) => {
                    missing = Some(ib.prompt.text());
                    note = Some(format!(
                        "No cached generation for this prompt ({e}). Press “Run the generator” \
                         to make it; until then the geometric branch runs alone and no views are \
                         shown (never views generated from another prompt)."
                    ));
                }
                Err(e) => {
                    note = Some(format!(
                        "image branch unavailable for {id}: {e} — fell back to the geometric \
                         branch alone"
                    ))
                }
            }
        }
        let (result, inputs) = match with_image {
            Some((r, i)) => {
                // keep its geometric branch for geometry-only runs of this pair
                self.geo
                    .entry((id.to_string(), params.voxel.to_bits()))
                    .or_insert_with(|| {
                        Arc::new(FusionInputs {
                            source_geo: i.source_geo.clone(),
                            target_geo: i.target_geo.clone(),
                            image: None,
                            image_label: None,
                        })
                    });
                (r, Some(Arc::new(i)))
            }
            None => {
                let mut gp = params.clone();
                gp.image = None;
                if gp.geo_features == crate::pipeline::params::GeoFeatureSource::Fpfh {
                    let t0 = Instant::now();
                    let (g, mut timings) = self.geometry(id, &pair, gp.voxel)?;
                    let mut r = fuse_and_finish(&pair, &gp, &g, None)?;
                    timings.append(&mut r.timings);
                    r.timings = timings;
                    r.total_ms = t0.elapsed().as_secs_f64() * 1e3;
                    (r, Some(g))
                } else {
                    // learned features: keep the inputs too (posteriors, export)
                    let (r, i) = crate::pipeline::register_pair_cached_keep(&pair, &gp, None)?;
                    (r, Some(Arc::new(i)))
                }
            }
        };
        if let Some(img) = &result.image {
            let asked = params
                .image
                .as_ref()
                .map(|ib| ib.prompt.text())
                .unwrap_or_default();
            // an empty provenance prompt: the backend used none (oracle)
            if !img.provenance.prompt.trim().is_empty()
                && img.provenance.prompt.trim() != asked.trim()
            {
                note = Some(format!(
                    "these views were generated with the prompt “{}”, not the one in the editor \
                     (the {} backend cannot regenerate them)",
                    img.provenance.prompt, img.provenance.backend
                ));
            }
        }
        let label = self.fusion_label(&result);
        let mut model = result_to_model(&pair, &result, &label, self.pairs.clone());
        if params.image.is_some() {
            model.image_branch_note = note.clone();
        }
        model.generation_missing = missing.clone();
        self.studies.fill(&mut model.plots);
        self.pairs = model.pairs.clone();
        let kept = inputs.map(|inputs| Kept {
            signature: sig,
            sims: similarities(&inputs).ok().map(Arc::new),
            inputs,
            image: result.image.clone(),
            stages: model.stages.clone(),
            note: model.image_branch_note.clone(),
            generation_missing: missing,
        });
        self.current = Some(Current {
            pair,
            result,
            model,
            kept,
        });
        Ok(self.with_default_posterior())
    }

    /// The current model with the posterior of [`default_posterior_point`] added (the
    /// posterior tab opens on it); the model unchanged when no posterior can be formed.
    fn with_default_posterior(&mut self) -> InspectorModel {
        let chosen = self
            .current
            .as_ref()
            .and_then(|c| default_posterior_point(&c.model.matches));
        if let Some((src, why)) = chosen {
            if let Ok(m) = self.inspect_point(src) {
                if let Some(c) = self.current.as_mut() {
                    if let Some(p) = c
                        .model
                        .posteriors
                        .iter_mut()
                        .find(|p| p.source_point == src)
                    {
                        p.reason = why;
                    }
                    c.model.default_posterior = Some(src);
                    return c.model.clone();
                }
                return m;
            }
        }
        self.current
            .as_ref()
            .map(|c| c.model.clone())
            .unwrap_or_default()
    }

    fn fusion_label(&self, result: &RegistrationResult) -> String {
        match &result.image_branch {
            Some(_) => self.params.fusion.mode.label().to_string(),
            None => format!("geometry only ({}; image branch off)", result.geo_features),
        }
    }

    /// Re-runs similarity, fusion and estimation from memory when the current pair was run with
    /// the same image-branch settings (only calibration, fusion, selection or estimator
    /// changed). None: a full (cached) run is needed.
    pub fn refuse(&mut self) -> Option<crate::Result<InspectorModel>> {
        let params = self.params.clone();
        let sig = signature(&params);
        let label_settings = self.params.fusion.mode;
        let cur = self.current.as_mut()?;
        let kept = cur.kept.as_ref()?;
        if kept.signature != sig {
            return None;
        }
        let t0 = Instant::now();
        let run = fuse_and_finish(&cur.pair, &params, &kept.inputs, kept.sims.as_deref());
        let mut result = match run {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        result.image = kept.image.clone();
        let label = match &result.image_branch {
            Some(_) => label_settings.label().to_string(),
            None => format!("geometry only ({}; image branch off)", result.geo_features),
        };
        let mut model = result_to_model(&cur.pair, &result, &label, self.pairs.clone());
        let mut stages: Vec<StageInfo> = kept
            .stages
            .iter()
            .filter(|s| {
                !matches!(
                    s.name.as_str(),
                    "similarity" | "fusion" | "estimate" | "similarity+fusion"
                )
            })
            .map(|s| StageInfo {
                name: s.name.clone(),
                state: StageState::Cached,
                time_ms: Some(0.0),
            })
            .collect();
        stages.append(&mut model.stages);
        stages.insert(
            0,
            StageInfo {
                name: "re-fuse from memory".into(),
                state: StageState::Done,
                time_ms: Some(t0.elapsed().as_secs_f64() * 1e3),
            },
        );
        model.stages = stages;
        if result.image.is_some() || kept.note.is_some() {
            model.image_branch_note = kept.note.clone();
        }
        model.generation_missing = kept.generation_missing.clone();
        self.studies.fill(&mut model.plots);
        self.pairs = model.pairs.clone();
        cur.model = model;
        cur.result = result;
        Some(Ok(self.with_default_posterior()))
    }

    /// Writes the current pair's selected correspondences to `path` (an `.npz`, see
    /// [`crate::pipeline::export`]) from the kept fusion inputs; returns how many.
    pub fn export_correspondences(&self, path: &Path) -> crate::Result<usize> {
        let cur = self
            .current
            .as_ref()
            .ok_or_else(|| crate::Error::Invalid("no registered pair to export".into()))?;
        let kept = cur.kept.as_ref().ok_or_else(|| {
            crate::Error::Invalid("the fusion inputs of this pair were not kept".into())
        })?;
        let t = crate::pipeline::export::export_correspondences(
            path,
            &cur.pair,
            &self.params,
            &kept.inputs,
            kept.sims.as_deref(),
            &cur.result,
        )?;
        Ok(t.len())
    }

    /// Adds the estimator's ranked hypotheses to the current model (an explanation instead
    /// when there are none or they could not be formed).
    pub fn hypotheses(&mut self) -> crate::Result<InspectorModel> {
        use super::hypotheses_panel::HypothesisList;
        let params = self.params.clone();
        let cur = self
            .current
            .as_mut()
            .ok_or_else(|| crate::Error::Invalid("no registered pair".into()))?;
        let list = match crate::pipeline::hypotheses::estimator_hypotheses(
            &cur.result,
            &params,
            cur.pair.gt_target_from_source.as_ref(),
            crate::estimate::hypotheses::DEFAULT_TOP_N,
        ) {
            Ok(Some(r)) => HypothesisList::from_ranked(&r),
            Ok(None) => HypothesisList::none(format!(
                "{} forms no hypotheses: one least-squares solution",
                cur.result.estimator
            )),
            Err(e) => HypothesisList::none(format!("no hypotheses: {e}")),
        };
        cur.model.hypotheses = Some(list);
        Ok(cur.model.clone())
    }

    /// Adds the branch posteriors of source keypoint `src` to the current model.
    pub fn inspect_point(&mut self, src: usize) -> crate::Result<InspectorModel> {
        let fusion = self.params.fusion;
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
        let kept = cur.kept.as_ref().ok_or_else(|| {
            crate::Error::Invalid(
                "posteriors are computed for FPFH features only in this build".into(),
            )
        })?;
        let survived = cur
            .model
            .matches
            .iter()
            .find(|m| m.src == src)
            .and_then(|m| m.survived);
        let sims = match &kept.sims {
            Some(s) => s.clone(),
            None => Arc::new(similarities(&kept.inputs)?),
        };
        let post = point_posterior(
            &kept.inputs,
            &sims,
            kept.image.as_ref(),
            &fusion,
            src,
            cur.pair.gt_target_from_source.as_ref(),
            survived,
        )?;
        let mut post = post;
        post.reason = "chosen by click".into();
        cur.model.posteriors.retain(|p| p.source_point != src);
        cur.model.posteriors.push(post);
        Ok(cur.model.clone())
    }

    fn report(
        &mut self,
        id: &str,
        t: Instant,
        r: crate::Result<InspectorModel>,
        stage: &str,
        events: &EventSink,
    ) {
        match r {
            Ok(mut model) => {
                self.studies.fill(&mut model.plots);
                model.plots.figure7_pending = self.figure7_possible();
                let ms = t.elapsed().as_secs_f64() * 1e3;
                if model.stages.first().is_none_or(|s| s.name != stage) {
                    model.stages.insert(
                        0,
                        StageInfo {
                            name: stage.into(),
                            state: StageState::Done,
                            time_ms: Some(ms),
                        },
                    );
                }
                let msg = match model.current_pair.and_then(|i| model.pairs.get(i)) {
                    Some(PairEntry {
                        rre_deg: Some(r),
                        rte_m: Some(e),
                        ..
                    }) => format!(
                        "{id}: RRE {r:.2}° RTE {:.1} cm, {} matches, {ms:.0} ms ({stage})",
                        e * 100.0,
                        model.matches.len()
                    ),
                    _ => format!(
                        "{id}: registered, {} matches, {ms:.0} ms ({stage})",
                        model.matches.len()
                    ),
                };
                if let Some(c) = self.current.as_mut() {
                    c.model = model.clone();
                    for w in &c.result.warnings {
                        events.log(LogLevel::Warn, format!("{id}: {w}"));
                    }
                }
                events.log(LogLevel::Info, msg);
                if let Some(n) = &model.image_branch_note {
                    let level = if model.generation_missing.is_some()
                        || model.source_views.is_empty() && self.params.image.is_some()
                    {
                        LogLevel::Warn
                    } else {
                        LogLevel::Info
                    };
                    events.log(level, n.clone());
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
                    name: stage.into(),
                    state: StageState::Failed(e.to_string()),
                    time_ms: Some(t.elapsed().as_secs_f64() * 1e3),
                }];
                model.image_branch_note = Some(format!("registration failed: {e}"));
                self.current = None;
                events.send(WorkerEvent::Model(Box::new(model)));
                events.log(LogLevel::Error, msg);
            }
        }
    }

    /// The paper's figure 7: precision-recall of the fused matches under Noisy-AND and under
    /// Noisy-OR (a match is correct within 5 cm under the ground truth, as in appendix D), from
    /// the kept similarities with the current calibration and selection. None without the
    /// image branch or ground truth.
    pub fn fusion_pr_curves(&self) -> Option<Vec<PrCurve>> {
        let cur = self.current.as_ref()?;
        let kept = cur.kept.as_ref()?;
        let sims = kept.sims.as_ref()?;
        let (s_img, vs, vt) = sims.image.as_ref()?;
        let gt = cur.pair.gt_target_from_source?;
        let params = self.params.clone();
        let sk = &kept.inputs.source_geo.keypoints.points;
        let tk = &kept.inputs.target_geo.keypoints.points;
        let curves: Vec<PrCurve> = [
            (FusionMode::NoisyAnd, "Noisy-AND"),
            (FusionMode::NoisyOr, "Noisy-OR"),
        ]
        .into_iter()
        .filter_map(|(mode, name)| {
            let mut f = params.fusion;
            f.mode = mode;
            let corr = crate::fusion::match_then_fuse_select(
                Some((s_img, Some(vs.as_slice()), Some(vt.as_slice()))),
                Some(&sims.geo),
                &f,
            )
            .ok()?;
            let matches: Vec<MatchInfo> = corr
                .iter()
                .filter_map(|c| {
                    let (sp, tp) = (sk.get(c.src as usize)?, tk.get(c.tgt as usize)?);
                    let d = (gt * sp.cast::<f64>() - tp.cast::<f64>()).norm();
                    Some(MatchInfo {
                        src: c.src as usize,
                        tgt: c.tgt as usize,
                        score: c.score,
                        inlier_gt: Some(d < FIGURE7_CORRECT_M),
                        branch: Branch::Both,
                        survived: None,
                    })
                })
                .collect();
            pr_curve(&format!("{name} ({} matches)", matches.len()), &matches)
        })
        .collect();
        (curves.len() == 2).then_some(curves)
    }

    /// Whether [`Self::fusion_pr_curves`] has what it needs (kept image similarity, GT).
    fn figure7_possible(&self) -> bool {
        self.current.as_ref().is_some_and(|c| {
            c.pair.gt_target_from_source.is_some()
                && c.kept
                    .as_ref()
                    .and_then(|k| k.sims.as_ref())
                    .is_some_and(|s| s.image.is_some())
        })
    }

    /// Puts both figure-7 curves into the current model and sends it, once per model.
    fn send_figure7(&mut self, events: &EventSink) {
        if !self
            .current
            .as_ref()
            .is_some_and(|c| c.model.plots.figure7_pending)
        {
            return;
        }
        let curves = self.fusion_pr_curves();
        if let Some(c) = self.current.as_mut() {
            c.model.plots.figure7_pending = false;
            if let Some(curves) = curves {
                c.model.plots.pr_curves = curves;
            }
            events.send(WorkerEvent::Model(Box::new(c.model.clone())));
        }
    }

    fn run_and_report(&mut self, id: &str, generate: bool, events: &EventSink) {
        events.send(WorkerEvent::Stage(StageInfo {
            name: "load + register".into(),
            state: StageState::Running,
            time_ms: None,
        }));
        if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
            p.status = PairStatus::Running;
        }
        let t = Instant::now();
        let r = self.run_pair_with(id, generate);
        self.report(id, t, r, "load + register", events);
    }
}

impl Worker for PipelineWorker {
    fn cancel_flag(&self) -> Option<Arc<std::sync::atomic::AtomicBool>> {
        Some(self.cancel.clone())
    }

    fn handle(&mut self, command: Command, events: &EventSink) {
        match command {
            Command::SelectPair(id) => self.run_and_report(&id, true, events),
            Command::OpenPairWith { pair, params } => {
                self.params = params;
                self.run_and_report(&pair, true, events);
            }
            Command::Figure7 => self.send_figure7(events),
            Command::ApplySettings(s) => {
                // a new prompt or seed is not generated without asking (the button)
                let gen_of = |p: &RegisterParams| p.image.as_ref().map(|i| (i.prompt.text(), i.seed));
                let generate = gen_of(&s) == gen_of(&self.params);
                self.params = s;
                let Some(id) = self.current.as_ref().map(|c| c.result.pair_id.clone()) else {
                    events.log(LogLevel::Info, "settings stored; no pair selected yet");
                    return;
                };
                let t = Instant::now();
                match self.refuse() {
                    Some(r) => self.report(&id, t, r, "re-fuse from memory", events),
                    None => self.run_and_report(&id, generate, events),
                }
            }
            Command::RunStudy(req) => self.study(req, events),
            Command::InspectSourcePoint(i) => match self.inspect_point(i) {
                Ok(m) => events.send(WorkerEvent::Model(Box::new(m))),
                Err(e) => events.log(LogLevel::Warn, format!("posterior of point {i}: {e}")),
            },
            Command::Open { kind, paths } => {
                self.open(kind, paths, events);
            }
            Command::OpenOrFallback {
                kind,
                paths,
                fallback_pair,
            } => {
                events.log(
                    LogLevel::Info,
                    format!("reopening the last opened data: {paths:?}"),
                );
                if !self.open(kind, paths, events) {
                    events.log(
                        LogLevel::Error,
                        format!("could not reopen the last opened data; showing {fallback_pair}"),
                    );
                    self.run_and_report(&fallback_pair, true, events);
                }
            }
            Command::RunGenerator { prompt } => {
                let Some(ib) = &self.params.image else {
                    events.log(
                        LogLevel::Warn,
                        "no generator configured: choose a WFM under “Image branch”",
                    );
                    return;
                };
                let backend = ib.backend.label();
                if prompt.trim() != ib.prompt.text().trim() {
                    events.log(
                        LogLevel::Warn,
                        "the prompt changed since the request; generating for the prompt in the editor",
                    );
                }
                match self.current.as_ref().map(|c| c.result.pair_id.clone()) {
                    Some(id) => {
                        events.log(
                            LogLevel::Info,
                            format!("{id}: running the generator ({backend})"),
                        );
                        self.run_and_report(&id, true, events)
                    }
                    None => events.log(LogLevel::Warn, "select a pair first"),
                }
            }
            Command::ExportCorrespondences(path) => match self.export_correspondences(&path) {
                Ok(n) => events.log(
                    LogLevel::Info,
                    format!("wrote {n} correspondences to {}", path.display()),
                ),
                Err(e) => events.log(LogLevel::Error, format!("export correspondences: {e}")),
            },
            Command::Hypotheses => match self.hypotheses() {
                Ok(m) => events.send(WorkerEvent::Model(Box::new(m))),
                Err(e) => events.log(LogLevel::Warn, format!("hypotheses: {e}")),
            },
            Command::Cancel => events.log(
                LogLevel::Info,
                "cancel: a running study stops before its next pair; registrations run to completion",
            ),
        }
    }
}

impl PipelineWorker {
    /// The settings of a study request: K values, or the four prompt presets with the editor's
    /// prefix plus the editor's scene as "custom" when it is none of the presets.
    pub fn study_settings(&self, req: &StudyRequest) -> Vec<StudySetting> {
        match req {
            StudyRequest::K(ks) => k_settings(ks),
            StudyRequest::Prompt => {
                let prompt = self
                    .params
                    .image
                    .as_ref()
                    .map(|ib| ib.prompt.clone())
                    .unwrap_or_else(|| ImageBranchParams::default().prompt);
                let scene = prompt.scene.trim();
                let custom = crate::wfm::PromptPreset::of_scene(scene)
                    .is_none()
                    .then_some(scene);
                prompt_settings(prompt.prefix.trim(), custom)
            }
        }
    }

    /// Runs a study over every pair of the open dataset with the current settings (through
    /// the stage cache; a generation is produced when missing except for a Cosmos command),
    /// reporting progress, and keeps its plots. Synchronous (the worker thread).
    pub fn run_study(
        &mut self,
        req: &StudyRequest,
        progress: &mut dyn FnMut(usize, usize),
    ) -> crate::Result<StudyReport> {
        let params = self.params.clone();
        let settings = self.study_settings(req);
        let generate = !matches!(
            params.image.as_ref().map(|i| &i.backend),
            Some(WfmSpec::Cosmos { .. })
        );
        let ids = self.pair_ids();
        let (loaded, dataset) = (&self.loaded, &self.dataset);
        let rep = run_study_with(
            &ids,
            &mut |id| match loaded.get(id) {
                Some(p) => Ok(p.clone()),
                None => dataset.load_pair(id),
            },
            &params,
            &settings,
            self.cache.as_deref(),
            generate,
            &mut |p| progress(p.done, p.total),
            Some(&self.cancel),
        )?;
        let (k, p) = study_plots(&rep);
        let runs: usize = rep.rows.iter().map(|r| r.pairs_run).sum();
        let source = format!("{} · {} pairs", rep.label(), rep.pairs.len());
        match req {
            StudyRequest::K(_) => {
                self.studies.vs_k = k;
                self.studies.vs_k_source = if runs == 0 {
                    format!("no pair ran ({source})")
                } else {
                    source
                };
            }
            StudyRequest::Prompt => {
                self.studies.prompt = p;
                self.studies.prompt_source = if runs == 0 {
                    format!("no pair ran ({source})")
                } else {
                    source
                };
            }
        }
        Ok(rep)
    }

    fn study(&mut self, req: StudyRequest, events: &EventSink) {
        let what = match &req {
            StudyRequest::K(_) => "K sweep",
            StudyRequest::Prompt => "prompt study",
        };
        if self.params.image.is_none() {
            events.log(
                LogLevel::Warn,
                format!("{what}: choose a WFM under “Image branch” first (a study needs the image branch)"),
            );
            return;
        }
        events.log(
            LogLevel::Info,
            format!(
                "{what}: {} pairs with the current settings…",
                self.pairs.len()
            ),
        );
        let t = Instant::now();
        self.cancel
            .store(false, std::sync::atomic::Ordering::Relaxed);
        let r = self.run_study(&req, &mut |done, total| {
            events.send(WorkerEvent::Progress(what.to_string(), done, total))
        });
        match r {
            Ok(rep) => {
                for row in &rep.rows {
                    if let Some(why) = &row.setting_skipped {
                        events.log(
                            LogLevel::Warn,
                            format!("{what}: {} skipped: {why}", row.setting),
                        );
                    }
                    for n in row.skipped.iter().chain(&row.failed) {
                        events.log(
                            LogLevel::Warn,
                            format!("{what}: {} · {}: {}", row.setting, n.pair_id, n.reason),
                        );
                    }
                    if let (Some(r), Some(e)) = (row.rre_mean_deg, row.rte_mean_m) {
                        events.log(
                            LogLevel::Info,
                            format!(
                                "{what}: {}: mean RRE {r:.2}° RTE {:.1} cm over {} pairs",
                                row.setting,
                                e * 100.0,
                                row.pairs_run
                            ),
                        );
                    }
                }
                for n in &rep.notes {
                    events.log(LogLevel::Warn, format!("{what}: {n}"));
                }
                events.log(
                    LogLevel::Info,
                    format!(
                        "{what} done in {:.1} s ({})",
                        t.elapsed().as_secs_f64(),
                        rep.label()
                    ),
                );
            }
            Err(e) => events.log(LogLevel::Error, format!("{what}: {e}")),
        }
        events.send(WorkerEvent::Progress(what.to_string(), 1, 1));
        let mut model = match &self.current {
            Some(c) => c.model.clone(),
            None => InspectorModel::default(),
        };
        model.pairs = self.pairs.clone();
        self.studies.fill(&mut model.plots);
        if let Some(c) = self.current.as_mut() {
            c.model = model.clone();
        }
        events.send(WorkerEvent::Model(Box::new(model)));
    }

    /// Turns what was opened into a dataset, loads its first pair (so a bad file fails here,
    /// with the previous dataset still loaded), then replaces the dataset and registers it.
    /// False when nothing was opened (the error is logged).
    fn open(&mut self, kind: super::OpenKind, paths: Vec<PathBuf>, events: &EventSink) -> bool {
        let what = paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ");
        let kind = match kind {
            super::OpenKind::Auto => crate::dataset::open::classify_drop(&paths),
            k => k,
        };
        if kind == super::OpenKind::CosmosOutput {
            return self.open_cosmos_output(&paths, events);
        }
        let t = Instant::now();
        match crate::dataset::open::open_dataset(kind, &paths) {
            Ok(d) => {
                let d = d.with_fragment_cache(
                    Cache::open(crate::pipeline::cache::default_cache_dir()).ok(),
                );
                let first = d.pairs().first().map(|p| p.id.clone());
                let pre = match &first {
                    Some(id) => match d.load_pair(id) {
                        Ok(p) => Some(p),
                        Err(e) => {
                            events.log(
                                LogLevel::Error,
                                format!(
                                    "{what}: {e} (loading pair {id}; the previous dataset stays open)"
                                ),
                            );
                            return false;
                        }
                    },
                    None => None,
                };
                events.log(
                    LogLevel::Info,
                    format!(
                        "loaded {} in {:.0} ms",
                        first.as_deref().unwrap_or("(no pairs)"),
                        t.elapsed().as_secs_f64() * 1e3
                    ),
                );
                self.replace_dataset(d, pre, &what, events);
                true
            }
            Err(e) => {
                events.log(
                    LogLevel::Error,
                    format!("{e} (the previous dataset stays open)"),
                );
                false
            }
        }
    }

    /// A Cosmos output folder: the image branch switches to it (cached Cosmos backend, the
    /// folder + its JSONL spec, as the Image-branch controls set them), the dataset stays, and
    /// the current pair re-runs. False (logged) when the folder or its spec is unusable.
    fn open_cosmos_output(&mut self, paths: &[PathBuf], events: &EventSink) -> bool {
        let r = match paths {
            [dir] => cosmos_output_settings(&self.params, dir).and_then(|s| {
                // the spec must parse (positional mapping) before the settings change
                if let Some(WfmSpec::Cached { dir, spec }) = s.image.as_ref().map(|i| &i.backend) {
                    crate::wfm::cached::CachedBackend::open(dir, spec)?;
                }
                Ok(s)
            }),
            _ => Err(crate::Error::Invalid(format!(
                "expected one Cosmos output folder, got {} paths",
                paths.len()
            ))),
        };
        let s = match r {
            Ok(s) => s,
            Err(e) => {
                events.log(
                    LogLevel::Error,
                    format!("{e} (the image branch settings stay as they were)"),
                );
                return false;
            }
        };
        if let Some(WfmSpec::Cached { dir, spec }) = s.image.as_ref().map(|i| &i.backend) {
            events.log(
                LogLevel::Info,
                format!(
                    "image branch: cached Cosmos output {} with spec {} (dataset unchanged)",
                    dir.display(),
                    spec.display()
                ),
            );
        }
        self.params = s.clone();
        events.send(WorkerEvent::Settings(Box::new(s)));
        let id = self
            .current
            .as_ref()
            .map(|c| c.result.pair_id.clone())
            .or_else(|| self.pairs.first().map(|p| p.id.clone()));
        match id {
            Some(id) => self.run_and_report(&id, true, events),
            None => events.log(LogLevel::Warn, "the dataset lists no pairs"),
        }
        true
    }

    fn replace_dataset(
        &mut self,
        d: Dataset,
        first: Option<ScanPair>,
        what: &str,
        events: &EventSink,
    ) {
        let params = self.params.clone();
        let cache = self.cache.take();
        *self = Self::with_cache(d, params.clone(), cache, None);
        self.params = params;
        if let Some(p) = first {
            self.loaded.insert(p.id.clone(), p);
        }
        events.log(
            LogLevel::Info,
            format!("opened {what} ({} pairs)", self.pairs.len()),
        );
        match self.pairs.first().map(|p| p.id.clone()) {
            Some(id) => self.run_and_report(&id, true, events),
            None => events.log(LogLevel::Warn, "the dataset lists no pairs"),
        }
    }
}

/// Whether `p` is a Cosmos batch spec: a `.jsonl` file, or a `.json` file whose first line is a
/// batch line (an object with `prompt` and `control_overrides`, like the authors'
/// `generation_specs/3dmatch_test.json`) rather than a single JSON document.
fn is_batch_spec(p: &Path) -> bool {
    use std::io::BufRead;
    let ext = p
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if !p.is_file() {
        return false;
    }
    match ext.as_str() {
        "jsonl" => true,
        "json" => {
            let Ok(f) = std::fs::File::open(p) else {
                return false;
            };
            let mut line = String::new();
            let mut r = std::io::BufReader::new(f);
            while line.trim().is_empty() {
                line.clear();
                if r.read_line(&mut line).map_or(true, |n| n == 0) {
                    return false;
                }
            }
            serde_json::from_str::<serde_json::Value>(line.trim())
                .is_ok_and(|v| v.get("prompt").is_some() && v.get("control_overrides").is_some())
        }
        _ => false,
    }
}

/// The JSONL batch spec of a Cosmos output folder, searched in the folder, its parent, and the
/// authors' published layout (`generation_specs/` next to `generated_videos/`). Where one place
/// holds several specs, the one named like the folder wins (`3dmatch_rgb_gen_vids` ->
/// `3dmatch_test.json`); none or several left is an error naming the places and files.
pub fn find_cosmos_spec(dir: &Path) -> crate::Result<PathBuf> {
    use crate::Error;
    if !dir.is_dir() {
        return Err(Error::format(
            dir,
            "folder",
            "a Cosmos output folder (video_<i>/output.mp4)",
            "not a folder",
        ));
    }
    let has_videos = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .flatten()
        .any(|e| e.file_name().to_string_lossy().starts_with("video_") && e.path().is_dir());
    if !has_videos {
        return Err(Error::format(
            dir,
            "video_<i>/ folders",
            "a Cosmos output folder (video_<i>/output.mp4)",
            "no video_<i> folder",
        ));
    }
    let specs_in = |d: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(d)
            .map(|rd| {
                rd.flatten()
                    .map(|e| e.path())
                    .filter(|p| is_batch_spec(p))
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    };
    let names = |v: &[PathBuf]| {
        v.iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    // "3dmatch_rgb_gen_vids" -> "3dmatch"
    let word = dir
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .and_then(|n| n.split(['_', '-', '.']).next().map(str::to_owned))
        .unwrap_or_default();
    let mut places = vec![dir.to_path_buf()];
    if let Some(parent) = dir.parent() {
        places.push(parent.to_path_buf());
        places.push(parent.join("generation_specs"));
        if let Some(gp) = parent.parent() {
            places.push(gp.join("generation_specs"));
        }
    }
    places.dedup();
    for d in &places {
        let found = specs_in(d);
        match found.as_slice() {
            [] => continue,
            [one] => return Ok(one.clone()),
            many => {
                let named: Vec<PathBuf> = many
                    .iter()
                    .filter(|p| {
                        !word.is_empty()
                            && p.file_name().is_some_and(|n| {
                                n.to_string_lossy().to_ascii_lowercase().starts_with(&word)
                            })
                    })
                    .cloned()
                    .collect();
                if let [one] = named.as_slice() {
                    return Ok(one.clone());
                }
                return Err(Error::Invalid(format!(
                    "{}: several JSONL batch specs ({}), none named like {}; choose one under \
                     Image branch > JSONL spec",
                    d.display(),
                    names(many),
                    dir.display()
                )));
            }
        }
    }
    Err(Error::Invalid(format!(
        "no JSONL batch spec (*.jsonl, or a .json of JSON lines) for the Cosmos output folder \
         {}: looked in {}; put the spec there or choose it under Image branch > JSONL spec",
        dir.display(),
        names(&places)
    )))
}

/// `s` with the image branch switched to the cached Cosmos output in `dir` and its spec
/// ([`find_cosmos_spec`]); everything else unchanged.
pub fn cosmos_output_settings(p: &RegisterParams, dir: &Path) -> crate::Result<RegisterParams> {
    let spec = find_cosmos_spec(dir)?;
    let mut p = p.clone();
    p.image
        .get_or_insert_with(ImageBranchParams::default)
        .backend = WfmSpec::Cached {
        dir: dir.to_path_buf(),
        spec,
    };
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(src: usize, score: f32, inlier: Option<bool>) -> MatchInfo {
        MatchInfo {
            src,
            tgt: src + 100,
            score,
            inlier_gt: inlier,
            branch: Branch::Both,
            survived: None,
        }
    }

    #[test]
    fn default_point_is_the_strongest_wrong_match_else_the_strongest() {
        let ms = [
            m(1, 0.9, Some(true)),
            m(2, 0.5, Some(false)),
            m(3, 0.7, Some(false)),
            m(4, 0.95, Some(true)),
        ];
        let (src, why) = default_posterior_point(&ms).unwrap();
        assert_eq!(src, 3);
        assert!(
            why.contains("fails under GT") && why.contains("rank 3 of 4"),
            "{why}"
        );
        assert!(why.contains("2 of 4"), "{why}");
        let ok = [m(1, 0.9, Some(true)), m(4, 0.95, Some(true))];
        let (src, why) = default_posterior_point(&ok).unwrap();
        assert_eq!(src, 4);
        assert!(why.contains("within 10 cm"), "{why}");
        let (src, why) = default_posterior_point(&[m(7, 0.2, None), m(8, 0.1, None)]).unwrap();
        assert_eq!(src, 7);
        assert!(why.contains("no ground truth"), "{why}");
        assert!(default_posterior_point(&[]).is_none());
    }
}
