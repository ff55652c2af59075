//! What a registration produces (result, views, stage timings) and the timer that records
//! the stages. A leaf module: the stages and the registration entry points all use it.

use super::arbitration::{ScaleReport, VisibilityReport};
use super::graph::{Plan, StageName};
use super::inputs::FusionInputs;
use crate::error::Result;
use crate::fusion::Correspondence;
use crate::metrics::PairMetrics;
use nalgebra::{Isometry3, Point3};
use serde::Serialize;
use std::time::Instant;

#[derive(Clone, Debug, Serialize)]
pub struct StageTiming {
    /// The step as people read it ("fpfh source", "lift target", "estimate"): the JSON's name.
    pub stage: String,
    /// The graph stage it belongs to (None: outside the graph, e.g. loading the pair); what
    /// code matches on.
    #[serde(skip)]
    pub name: Option<StageName>,
    pub ms: f64,
    /// "computed" or "cached".
    pub status: String,
}

/// One selected view of the image branch, as shown in the GUI.
#[derive(Clone, Debug)]
pub struct ViewInfo {
    /// The (generated, oracle or built-in) RGB frame the VFM saw.
    pub image: image::RgbImage,
    /// Index into the generated video, and into the scan's depth frames.
    pub generated_index: usize,
    pub depth_index: usize,
    /// Backend, prompt and cache entry, e.g. "oracle (real RGB) | cache 3f2a..".
    pub label: String,
    /// The sensor (or virtual) depth frame the view was generated from.
    pub depth_path: Option<std::path::PathBuf>,
    /// Its camera pose in the scan: p_scan = scan_from_camera * p_camera.
    pub scan_from_camera: Option<Isometry3<f64>>,
    /// Its camera model (depth in this model's convention: z or range).
    pub camera: crate::camera::CameraModel,
}

/// What the image branch produced for one pair (None in `RegistrationResult` when it was off).
#[derive(Clone, Debug)]
pub struct ImageBranchOutput {
    pub source_views: Vec<ViewInfo>,
    pub target_views: Vec<ViewInfo>,
    /// Pixel of each source / target keypoint in its view (None: no pixel within the radius).
    pub source_links: Vec<Option<crate::vfm::lift::PixelLink>>,
    pub target_links: Vec<Option<crate::vfm::lift::PixelLink>>,
    pub provenance: crate::wfm::backend::Provenance,
    /// The VFM that described the views, e.g. "xfeat (onnx, native ORT 1.31)".
    pub vfm: String,
}

/// Everything a registration produced, for the CLI, JSON output and the GUI.
#[derive(Clone, Debug, Serialize)]
pub struct RegistrationResult {
    pub pair_id: String,
    pub source_name: String,
    pub target_name: String,
    /// Estimated p_target = T * p_source, as a row-major 4x4.
    pub target_from_source: [[f64; 4]; 4],
    #[serde(skip)]
    pub estimate: Isometry3<f64>,
    pub gt_target_from_source: Option<[[f64; 4]; 4]>,
    pub metrics: Option<PairMetrics>,
    /// The distance (m) under which a correspondence counts as a GT inlier (the metrics'
    /// inlier ratio, the inspector's inlier colours): the run's inlier threshold.
    pub gt_inlier_threshold_m: f64,
    /// Whether the ground truth or its inverse explains the data better (None without GT);
    /// its warning is also in `warnings`.
    pub convention: Option<crate::metrics::convention::ConventionCheck>,
    pub estimator: String,
    pub warnings: Vec<String>,
    /// Label of the geometric features actually used (e.g. "fpfh(v=0.050)").
    pub geo_features: String,
    /// Label of the image branch, None when it was off.
    pub image_branch: Option<String>,
    pub n_source_keypoints: usize,
    pub n_target_keypoints: usize,
    pub n_correspondences: usize,
    pub n_inliers: usize,
    pub timings: Vec<StageTiming>,
    pub total_ms: f64,
    #[serde(skip)]
    pub source_keypoints: Vec<Point3<f32>>,
    #[serde(skip)]
    pub target_keypoints: Vec<Point3<f32>>,
    #[serde(skip)]
    pub correspondences: Vec<Correspondence>,
    #[serde(skip)]
    pub inliers: Vec<usize>,
    #[serde(skip)]
    pub image: Option<ImageBranchOutput>,
    /// The `union` fusion's report: the sets it merged and where its inliers came from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub union: Option<crate::fusion::union::UnionReport>,
    /// The `visibility` fusion's report: every candidate pose's score and the one kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub visibility: Option<VisibilityReport>,
    /// The scale search's report: every hypothesis's voxel and visibility, and the one kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scales: Option<ScaleReport>,
    /// The in-memory tail's inputs, when the registration kept them
    /// ([`super::Registration::keep`]): what a re-fusion, the correspondence export and the
    /// posterior inspector recompute from.
    #[serde(skip)]
    pub inputs: Option<std::sync::Arc<FusionInputs>>,
    /// The plan this registration ran, every key filled as its step ran (None for a re-fusion
    /// from memory, whose caller keeps the plan): what a later settings change is compared
    /// with ([`Plan::invalidated_by`]).
    #[serde(skip)]
    pub plan: Option<Plan>,
}

impl RegistrationResult {
    /// The fusion's provenance line ("fusion: union (1030 Noisy-AND + 6256 geometry ...)",
    /// "fusion: visibility (kept the ... pose; ...)"), for the `union` and `visibility` modes;
    /// None for the other modes (their label says the mode).
    pub fn fusion_provenance(&self) -> Option<String> {
        match (&self.visibility, &self.union) {
            (Some(v), Some(u)) => Some(format!("{}; {}", v.provenance(), u.provenance())),
            (Some(v), None) => Some(v.provenance()),
            (None, u) => u.as_ref().map(|d| d.provenance()),
        }
    }

    /// The image branch's label without the fusion the tail appended to it (`; fusion ...`):
    /// what ran, for a header that shows the fusion and its provenance on their own.
    pub fn image_branch_source(&self) -> Option<String> {
        self.image_branch.as_deref().map(without_fusion)
    }
}

/// `label` up to its `; fusion` suffix, its parenthesis closed (the tail writes
/// "GEN + VFM (K=.., ...; fusion MODE)" and the union "...; fusion: union (...))").
fn without_fusion(label: &str) -> String {
    match label.find("; fusion") {
        Some(i) => format!("{})", &label[..i]),
        None => label.to_owned(),
    }
}

pub fn matrix_rows(t: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m = t.to_homogeneous();
    let mut out = [[0.0; 4]; 4];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    out
}

/// Records the steps of a registration by stage ([`StageName`]) with their labels. The cached
/// stages record under their own name ([`Self::record_as`], `stages::Ctx::stage`); `record` and
/// `stage` record a step of the in-memory tail ([`StageName::Fusion`]: similarity, fusion,
/// estimate).
pub(crate) struct Timer {
    pub(crate) timings: Vec<StageTiming>,
    pub(crate) t0: Instant,
}

impl Timer {
    pub(crate) fn new() -> Self {
        Timer {
            timings: Vec::new(),
            t0: Instant::now(),
        }
    }
    /// Record a step of the in-memory tail that ran (or was kept) outside `stage`.
    pub(crate) fn record(&mut self, label: &str, elapsed: std::time::Duration, cached: bool) {
        self.record_as(StageName::Fusion, label, elapsed, cached);
    }
    /// Run `f` as a step of the in-memory tail and record its time.
    pub(crate) fn stage<T>(&mut self, label: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
        self.stage_as(StageName::Fusion, label, f)
    }
    /// Record a step of the stage `name` (shown as `label`) that ran (or was read from the
    /// cache) outside `stage_as`.
    pub(crate) fn record_as(
        &mut self,
        name: StageName,
        label: &str,
        elapsed: std::time::Duration,
        cached: bool,
    ) {
        self.timings.push(StageTiming {
            stage: label.to_string(),
            name: Some(name),
            ms: elapsed.as_secs_f64() * 1e3,
            status: status_word(cached).into(),
        });
    }
    /// Run `f` as an in-memory step of the stage `name` (shown as `label`) and record its time.
    pub(crate) fn stage_as<T>(
        &mut self,
        name: StageName,
        label: &str,
        f: impl FnOnce() -> Result<T>,
    ) -> Result<T> {
        crate::cancel::check()?;
        let t = Instant::now();
        let out = f()?;
        self.record_as(name, label, t.elapsed(), false);
        crate::cancel::check()?;
        Ok(out)
    }
}

/// The status word of a stage timing: "cached" (read from the cache or kept in memory) or
/// "computed".
pub fn status_word(hit: bool) -> &'static str {
    if hit {
        "cached"
    } else {
        "computed"
    }
}

/// Whether a [`StageTiming::status`] says the stage was served from the cache.
pub fn is_cached(status: &str) -> bool {
    status == status_word(true)
}

#[cfg(test)]
mod label_tests {
    use super::without_fusion;

    #[test]
    fn the_image_label_loses_its_fusion_suffix_once() {
        let base = "builtin + alike (K=2, m=1, L=8; 5 / 6 source / target keypoints with a pixel";
        let want = format!("{base})");
        assert_eq!(without_fusion(&format!("{base}; fusion NoisyAnd)")), want);
        let union = format!(
            "{base}; fusion: union (2 Noisy-AND + 3 geometry correspondences, 4 distinct; \
             inliers 3: 1 geometry only, 2 Noisy-AND only, 0 both))"
        );
        assert_eq!(without_fusion(&union), want);
        assert_eq!(without_fusion("oracle"), "oracle");
    }
}
