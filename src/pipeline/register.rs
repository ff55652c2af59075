//! One registration: geometric branch (and, when configured, the image branch), Match-then-Fuse,
//! pose estimation and evaluation against ground truth.

use super::cache::Cache;
use super::params::{GeoFeatureSource, RegisterParams};
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::estimate::{estimate_pose, Estimate};
use crate::features::fpfh::{compute_fpfh, FpfhParams};
use crate::features::Features;
use crate::fusion::{match_then_fuse_select, Correspondence};
use crate::geometry::knn::KdIndex;
use crate::geometry::normals::{estimate_normals, orient_towards_viewpoint};
use crate::geometry::voxel::voxel_downsample;
use crate::geometry::PointCloud;
use crate::metrics::PairMetrics;
use nalgebra::{Isometry3, Point3};
use serde::Serialize;
use std::time::Instant;

#[derive(Clone, Debug, Serialize)]
pub struct StageTiming {
    pub stage: String,
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
    /// Record a stage that ran (or was read from the cache) outside `stage`.
    pub(crate) fn record(&mut self, name: &str, elapsed: std::time::Duration, cached: bool) {
        self.timings.push(StageTiming {
            stage: name.to_string(),
            ms: elapsed.as_secs_f64() * 1e3,
            status: if cached { "cached" } else { "computed" }.into(),
        });
    }
    fn stage<T>(&mut self, name: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
        let t = Instant::now();
        let out = f()?;
        self.timings.push(StageTiming {
            stage: name.to_string(),
            ms: t.elapsed().as_secs_f64() * 1e3,
            status: "computed".into(),
        });
        Ok(out)
    }
}

/// Keypoints and their geometric features for one scan.
#[derive(Clone, Debug)]
pub struct GeoBranch {
    pub keypoints: PointCloud,
    pub features: Features,
    pub label: String,
}

/// FPFH on the voxel-downsampled cloud: normals from local PCA (radius 2v, 30 neighbours)
/// oriented towards the scan origin (the first camera of a fragment), features radius 5v.
pub fn fpfh_branch(cloud: &PointCloud, voxel: f64) -> Result<GeoBranch> {
    if cloud.is_empty() {
        return Err(Error::Invalid(
            "cannot compute FPFH of an empty cloud".into(),
        ));
    }
    let mut kp = voxel_downsample(cloud, voxel);
    let index = KdIndex::new(&kp.points);
    let params = FpfhParams::for_voxel(voxel);
    let mut normals = estimate_normals(
        &kp.points,
        &index,
        params.normal_radius,
        params.normal_max_nn,
    );
    orient_towards_viewpoint(&kp.points, &mut normals, Point3::origin());
    let features = compute_fpfh(&kp.points, &normals, &index, &params);
    kp.normals = Some(normals);
    Ok(GeoBranch {
        keypoints: kp,
        features,
        label: format!("fpfh(v={voxel:.3})"),
    })
}

fn geo_branches(
    pair: &ScanPair,
    params: &RegisterParams,
    timer: &mut Timer,
) -> Result<(GeoBranch, GeoBranch)> {
    match &params.geo_features {
        GeoFeatureSource::Fpfh => {
            let s = timer.stage("fpfh source", || {
                fpfh_branch(&pair.source.cloud, params.voxel)
            })?;
            let t = timer.stage("fpfh target", || {
                fpfh_branch(&pair.target.cloud, params.voxel)
            })?;
            Ok((s, t))
        }
        GeoFeatureSource::Files { source, target } => timer.stage("load learned features", || {
            let s = crate::features::learned::load_learned_features(source)?;
            let t = crate::features::learned::load_learned_features(target)?;
            Ok((
                GeoBranch {
                    keypoints: s.points,
                    features: s.feats,
                    label: s.source,
                },
                GeoBranch {
                    keypoints: t.points,
                    features: t.feats,
                    label: t.source,
                },
            ))
        }),
        GeoFeatureSource::GeoTransformerPkl { path } => timer.stage("load geotransformer", || {
            let (r, s) = crate::features::learned::load_geotransformer_pkl(path)?;
            // Reference §5 (3DMatch): GeoTransformer's ref is C-GenReg's source.
            Ok((
                GeoBranch {
                    keypoints: r.points,
                    features: r.feats,
                    label: r.source,
                },
                GeoBranch {
                    keypoints: s.points,
                    features: s.feats,
                    label: s.source,
                },
            ))
        }),
    }
}

/// Register `pair.source` onto `pair.target`: the geometric branch, plus the image branch
/// when `params.image` is set (everything computed in memory, no cache).
pub fn register_pair(pair: &ScanPair, params: &RegisterParams) -> Result<RegistrationResult> {
    register_pair_cached(pair, params, None)
}

/// [`register_pair`] with the image branch's stages read from / written to `cache`.
pub fn register_pair_cached(
    pair: &ScanPair,
    params: &RegisterParams,
    cache: Option<&Cache>,
) -> Result<RegistrationResult> {
    match &params.image {
        Some(ib) => super::image_branch::register_with_image(pair, params, ib, cache),
        None => register_geometry(pair, params),
    }
}

/// The geometric branch alone.
fn register_geometry(pair: &ScanPair, params: &RegisterParams) -> Result<RegistrationResult> {
    let mut timer = Timer::new();
    let (src, tgt) = geo_branches(pair, params, &mut timer)?;
    if src.features.dim != tgt.features.dim {
        return Err(Error::Invalid(format!(
            "source features are {}-D but target features are {}-D",
            src.features.dim, tgt.features.dim
        )));
    }
    // Without the image branch there is nothing to fuse: the geometric posterior is used alone.
    let mut fusion = params.fusion;
    fusion.mode = crate::fusion::FusionMode::GeometryOnly;
    let corr = match (fusion.selection, fusion.calibration_geo) {
        // Row softmax keeps each row's argmax, so nearest-neighbour selection needs no N x M
        // matrix (same result as the dense path; see fusion::streaming).
        (crate::fusion::Selection::RowNn, crate::fusion::Calibration::RowSoftmax { tau }) => timer
            .stage("similarity+calibrate+select", || {
                crate::fusion::streaming::row_nn_posterior(&src.features, &tgt.features, tau)
            })?,
        _ => {
            let sim = timer.stage("similarity", || {
                crate::fusion::similarity::cosine_similarity(&src.features, &tgt.features)
            })?;
            timer.stage("calibrate+select", || {
                match_then_fuse_select(None, Some(&sim), &fusion)
            })?
        }
    };
    finish(pair, params, timer, src, tgt, corr, None)
}

pub(crate) fn finish(
    pair: &ScanPair,
    params: &RegisterParams,
    mut timer: Timer,
    src: GeoBranch,
    tgt: GeoBranch,
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
        source_keypoints: src.keypoints.points,
        target_keypoints: tgt.keypoints.points,
        correspondences: corr,
        inliers: est.inliers,
        image: None,
    })
}
