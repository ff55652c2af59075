//! The full method: geometric branch (dense) + generated-RGB image branch, Match-then-Fuse.
//!
//! Stages and their cache keys (each key chains the keys of its inputs, see `pipeline::cache`):
//! - `geo-fpfh` per scan: cloud content hash + voxel -> keypoints, normals, FPFH;
//! - `depth-video`: content hashes of the first L depth frames of both scans + L -> the hash of
//!   the encoded video (reference §1). Frames are rebuilt in memory only when generation misses;
//! - `generation`: depth-video hash (+ colour-frame hashes for `oracle`) + prompt + backend id +
//!   seed -> all frames (PNG) and their provenance;
//! - view selection (K, m; in memory, trivial);
//! - `vfm-view` per selected view: generation key + frame index + model id -> descriptor grid;
//! - `lift` per scan: keypoints key + the selected views' depth hashes, poses, intrinsics,
//!   radius, image size -> pixel link of each keypoint (or none);
//! - `image-points`: lift and vfm keys -> one descriptor per keypoint + validity (reference
//!   §8.1: unmapped points are invalid).
//!
//! Cosine similarities, calibration, fusion, selection and estimation are cheap and run in
//! memory every time, so changing a temperature or the fusion mode recomputes only those.

use super::cache::{hash_file, Cache, CacheKey, Entry};
use super::params::{ImageBranchParams, RegisterParams, VfmSpec, WfmSpec};
use super::register::{finish, fpfh_branch, GeoBranch, ImageBranchOutput, Timer, ViewInfo};
use super::RegistrationResult;
use crate::dataset::{FrameSet, Scan, ScanPair};
use crate::error::{Error, Result};
use crate::features::Features;
use crate::fusion::{cosine_similarity, match_then_fuse_select};
use crate::geometry::PointCloud;
use crate::vfm::lift::{lift_views, LiftView, PixelLink};
use crate::vfm::pair_similarity::{pair_point_descriptors, PairPointDescriptors};
use crate::vfm::{DenseDescriptors, PairModel, PerImageModel};
use crate::wfm::backend::{GenerateRequest, Provenance, WfmBackend};
use image::RgbImage;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Depth clip used when lifting (reference §4: 5 m).
const LIFT_MAX_DEPTH: f32 = 5.0;
/// Range limit for f-theta (LiDAR) frames, in lifting and in the depth video: the reference's
/// indoor clips (5 m, 4 m) would flatten a LiDAR scan, so only the 16-bit millimetre range of
/// the depth PNGs limits them.
const LIDAR_MAX_RANGE: f32 = 65.0;

/// Depth-video clip (metres) for frames of `camera`: the reference's 4 m for RGB-D frames,
/// the whole range for LiDAR (f-theta) frames. The GUI shows depth frames with the same clip.
pub fn depth_video_clip(camera: &crate::camera::CameraModel) -> f64 {
    match camera {
        crate::camera::CameraModel::Pinhole(_) => crate::wfm::depth_video::CLIP_METERS,
        crate::camera::CameraModel::FTheta(_) => LIDAR_MAX_RANGE as f64,
    }
}

/// Lifting clip for frames of `camera`.
fn lift_max_depth(camera: &crate::camera::CameraModel) -> f32 {
    match camera {
        crate::camera::CameraModel::Pinhole(_) => LIFT_MAX_DEPTH,
        crate::camera::CameraModel::FTheta(_) => LIDAR_MAX_RANGE,
    }
}

struct Ctx<'a> {
    cache: Option<&'a Cache>,
    timer: Timer,
    warnings: Vec<String>,
}

impl Ctx<'_> {
    /// The cached value for `key` (verified), or `compute` then `store`. A corrupt entry is
    /// reported in the warnings, removed and recomputed, never used.
    fn cached<T>(
        &mut self,
        key: &CacheKey,
        load: impl FnOnce(&Entry) -> Result<T>,
        compute: impl FnOnce() -> Result<T>,
        store: impl FnOnce(&T, &Cache, &CacheKey) -> Result<()>,
    ) -> Result<(T, bool)> {
        if let Some(c) = self.cache {
            let problem = match c.get(key) {
                Ok(Some(e)) => match load(&e) {
                    Ok(v) => return Ok((v, true)),
                    Err(err) => Some(err.to_string()),
                },
                Ok(None) => None,
                Err(err) => Some(err.to_string()),
            };
            if let Some(p) = problem {
                self.warnings.push(format!(
                    "cache entry {} is corrupt ({p}); not used, recomputed",
                    key.short()
                ));
                let _ = c.remove(key);
            }
        }
        let v = compute()?;
        if let Some(c) = self.cache {
            if let Err(e) = store(&v, c, key) {
                self.warnings
                    .push(format!("could not write cache entry {}: {e}", key.short()));
            }
        }
        Ok((v, false))
    }

    fn stage<T>(
        &mut self,
        name: &str,
        key: &CacheKey,
        load: impl FnOnce(&Entry) -> Result<T>,
        compute: impl FnOnce() -> Result<T>,
        store: impl FnOnce(&T, &Cache, &CacheKey) -> Result<()>,
    ) -> Result<T> {
        let t = Instant::now();
        let (v, hit) = self.cached(key, load, compute, store)?;
        self.timer.record(name, t.elapsed(), hit);
        Ok(v)
    }
}

fn status_word(hit: bool) -> &'static str {
    if hit {
        "cached"
    } else {
        "computed"
    }
}

/// Content hash of a cloud's points (x, y, z little-endian f32).
fn cloud_hash(c: &PointCloud) -> String {
    let mut h = blake3::Hasher::new();
    for p in &c.points {
        h.update(&p.x.to_le_bytes());
        h.update(&p.y.to_le_bytes());
        h.update(&p.z.to_le_bytes());
    }
    h.finalize().to_hex().to_string()
}

fn points_flat(p: &[Point3<f32>]) -> Vec<f32> {
    p.iter().flat_map(|q| [q.x, q.y, q.z]).collect()
}

fn points_from(rows: usize, cols: usize, d: &[f32], what: &Path) -> Result<Vec<Point3<f32>>> {
    if cols != 3 || d.len() != rows * 3 {
        return Err(Error::format(
            what,
            "shape",
            "(N, 3)",
            format!("({rows}, {cols})"),
        ));
    }
    Ok(d.chunks(3).map(|c| Point3::new(c[0], c[1], c[2])).collect())
}

fn geo_cached(ctx: &mut Ctx, name: &str, scan: &Scan, voxel: f64) -> Result<(GeoBranch, CacheKey)> {
    let key = CacheKey::new(
        "geo-fpfh",
        1,
        &[&cloud_hash(&scan.cloud)],
        &json!({ "voxel": voxel, "n_points": scan.cloud.len() }),
    )?;
    let g = ctx.stage(
        name,
        &key,
        |e| {
            let (r, c, d) = e.read_f32_matrix("keypoints.npy")?;
            let points = points_from(r, c, &d, &e.path("keypoints.npy"))?;
            let (rn, cn, dn) = e.read_f32_matrix("normals.npy")?;
            let normals = points_from(rn, cn, &dn, &e.path("normals.npy"))?
                .into_iter()
                .map(|p| p.coords)
                .collect::<Vec<_>>();
            let features = e.read_features("fpfh.npy")?;
            if features.len() != points.len() || normals.len() != points.len() {
                return Err(Error::Cache(format!(
                    "{}: keypoints, normals and features disagree in length",
                    e.dir.display()
                )));
            }
            let mut kp = PointCloud::from_points(points);
            kp.normals = Some(normals);
            Ok(GeoBranch {
                keypoints: kp,
                features,
                label: format!("fpfh(v={voxel:.3})"),
            })
        },
        || fpfh_branch(&scan.cloud, voxel),
        |g, c, k| {
            let mut ne = c.put(k, json!({ "scan": scan.name, "features": g.label }))?;
            ne.add_f32_matrix(
                "keypoints.npy",
                g.keypoints.len(),
                3,
                &points_flat(&g.keypoints.points),
            )?;
            let normals: Vec<Point3<f32>> = g
                .keypoints
                .normals
                .as_ref()
                .map(|n| n.iter().map(|v| Point3::from(*v)).collect())
                .unwrap_or_default();
            ne.add_f32_matrix("normals.npy", normals.len(), 3, &points_flat(&normals))?;
            ne.add_features("fpfh.npy", &g.features)?;
            ne.commit()?;
            Ok(())
        },
    )?;
    Ok((g, key))
}

fn frames_of(scan: &Scan, l: usize) -> Result<&FrameSet> {
    let fs = scan.frames.as_ref().ok_or_else(|| {
        Error::Invalid(format!(
            "{}: the image branch needs the RGB-D frames the scan was made from (a raw-sequence \
             fragment, or a cloud with `frames` in the manifest)",
            scan.name
        ))
    })?;
    if fs.frames.len() < l {
        return Err(Error::Invalid(format!(
            "{}: {} frames, but the depth video needs L = {l} per fragment (set \
             frames_per_fragment / --frames)",
            scan.name,
            fs.frames.len()
        )));
    }
    Ok(fs)
}

#[derive(Serialize, Deserialize)]
struct VideoMeta {
    hash: String,
    frames: usize,
    width: u32,
    height: u32,
}

#[derive(Serialize, Deserialize)]
struct GenMeta {
    frames: usize,
    width: u32,
    height: u32,
}

/// Generated frames: in memory when just computed, read lazily from the cache entry on a hit.
struct GenOut {
    provenance: Provenance,
    meta: GenMeta,
    frames: Option<Vec<RgbImage>>,
    entry: Option<Entry>,
}

impl GenOut {
    fn frame(&self, i: usize) -> Result<RgbImage> {
        if let Some(f) = &self.frames {
            return f
                .get(i)
                .cloned()
                .ok_or_else(|| Error::Invalid(format!("generated frame {i} out of range")));
        }
        match &self.entry {
            Some(e) => e.read_png(&frame_name(i)),
            None => Err(Error::Invalid("generated frames are not available".into())),
        }
    }
}

fn frame_name(i: usize) -> String {
    format!("frames/{i:05}.png")
}

fn encode_png_fast(img: &RgbImage) -> Result<Vec<u8>> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let mut buf = Vec::new();
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| Error::Invalid(format!("encoding a frame as PNG: {e}")))?;
    Ok(buf)
}

/// The backend for `spec`; the built-in generator renders LiDAR pairs at the outdoor
/// resolution of the paper (appendix C: 1280x640), RGB-D pairs at 960x704.
fn make_backend(spec: &WfmSpec, lidar: bool) -> Result<Box<dyn WfmBackend>> {
    Ok(match spec {
        WfmSpec::Oracle => Box::new(crate::wfm::oracle::OracleBackend::default()),
        WfmSpec::Builtin if lidar => Box::new(crate::wfm::builtin::DepthShadeBackend {
            width: 1280,
            height: 640,
        }),
        WfmSpec::Builtin => Box::new(crate::wfm::builtin::DepthShadeBackend::default()),
        WfmSpec::Cached { dir, spec } => {
            Box::new(crate::wfm::cached::CachedBackend::open(dir, spec)?)
        }
        WfmSpec::Cosmos {
            command,
            work_dir,
            timeout_s,
        } => Box::new(crate::wfm::cosmos::CosmosBackend::new(
            crate::wfm::cosmos::CosmosConfig::new(
                command.clone(),
                work_dir.clone(),
                std::time::Duration::from_secs(*timeout_s),
            ),
        )?),
    })
}

/// Models stay loaded for the process (bench registers many pairs with one model): `load`
/// runs once per model file and kind.
fn memoized<T: ?Sized>(
    models: &OnceLock<Mutex<HashMap<PathBuf, Arc<T>>>>,
    model: &Path,
    load: impl FnOnce(&Path) -> Result<Arc<T>>,
) -> Result<Arc<T>> {
    let map = models.get_or_init(|| Mutex::new(HashMap::new()));
    let mut g = map
        .lock()
        .map_err(|_| Error::Invalid("VFM model cache poisoned".into()))?;
    if let Some(m) = g.get(model) {
        return Ok(m.clone());
    }
    let m = load(model)?;
    g.insert(model.to_path_buf(), m.clone());
    Ok(m)
}

fn load_vfm(spec: &VfmSpec) -> Result<Arc<dyn PerImageModel>> {
    static MODELS: OnceLock<Mutex<HashMap<PathBuf, Arc<dyn PerImageModel>>>> = OnceLock::new();
    match spec {
        VfmSpec::Xfeat { model } => memoized(&MODELS, model, load_xfeat),
        VfmSpec::Disk { model } | VfmSpec::Alike { model } => {
            memoized(&MODELS, model, |p| load_dense(spec, p))
        }
        VfmSpec::Mast3r { .. } => Err(Error::Invalid(format!(
            "{} is a pair-conditioned model, not a per-image one",
            spec.model().display()
        ))),
    }
}

#[cfg(feature = "onnx")]
fn load_dense(spec: &VfmSpec, path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Ok(Arc::new(crate::vfm::dense::DenseModel::load_spec(
        spec, path,
    )?))
}

#[cfg(not(feature = "onnx"))]
fn load_dense(_: &VfmSpec, path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Err(no_onnx(path))
}

fn load_pair_vfm(spec: &VfmSpec) -> Result<Arc<dyn PairModel>> {
    static MODELS: OnceLock<Mutex<HashMap<PathBuf, Arc<dyn PairModel>>>> = OnceLock::new();
    let VfmSpec::Mast3r { model } = spec else {
        return Err(Error::Invalid(format!(
            "{} is a per-image model, not a pair-conditioned one",
            spec.model().display()
        )));
    };
    memoized(&MODELS, model, load_mast3r)
}

#[cfg(feature = "onnx")]
fn load_xfeat(path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Ok(Arc::new(crate::vfm::xfeat::XFeat::load(path)?))
}

#[cfg(feature = "onnx")]
fn load_mast3r(path: &Path) -> Result<Arc<dyn PairModel>> {
    Ok(Arc::new(crate::vfm::mast3r::Mast3r::load(path)?))
}

#[cfg(not(feature = "onnx"))]
fn load_xfeat(path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Err(no_onnx(path))
}

#[cfg(not(feature = "onnx"))]
fn load_mast3r(path: &Path) -> Result<Arc<dyn PairModel>> {
    Err(no_onnx(path))
}

#[cfg(not(feature = "onnx"))]
fn no_onnx(path: &Path) -> Error {
    Error::Invalid(format!(
        "the image branch needs its VFM ({}) through ONNX, but cgenreg was built without the \
         `onnx` feature: rebuild with `--features onnx`",
        path.display()
    ))
}

/// Id of the VFM for cache keys, from the model file's content (no need to load it).
fn vfm_id(spec: &VfmSpec) -> Result<String> {
    let model = spec.model();
    if !model.is_file() {
        return Err(Error::Invalid(format!(
            "{}: {} ONNX model not found (see models/README.md, or pass --vfm-model)",
            model.display(),
            spec.name()
        )));
    }
    Ok(format!("{}@{}", spec.name(), &hash_file(model)?[..16]))
}

#[derive(Serialize, Deserialize)]
struct GridMeta {
    width: u32,
    height: u32,
    dim: usize,
    stride_x: f32,
    stride_y: f32,
}

type Link = Option<(u16, u32, u32)>;

/// One view of the lift stage's inputs: its depth file hash, pose and intrinsics.
// The inputs are the stage's cache key parts; bundling them in a struct would only rename them.
#[allow(clippy::too_many_arguments)]
fn lift_stage(
    ctx: &mut Ctx,
    name: &str,
    geo_key: &CacheKey,
    keypoints: &[Point3<f32>],
    fs: &FrameSet,
    depth_idx: &[usize],
    radius: f32,
    image_size: (u32, u32),
) -> Result<(Vec<Option<PixelLink>>, CacheKey)> {
    let paths: Vec<&Path> = depth_idx
        .iter()
        .map(|&i| {
            fs.frames
                .get(i)
                .map(|f| f.depth_path.as_path())
                .ok_or_else(|| Error::Invalid(format!("depth frame {i} out of range")))
        })
        .collect::<Result<_>>()?;
    let hashes: Vec<String> = paths
        .par_iter()
        .map(|p| hash_file(p))
        .collect::<Result<_>>()?;
    let mut inputs: Vec<&str> = vec![geo_key.hash.as_str()];
    inputs.extend(hashes.iter().map(String::as_str));
    let max_depth = lift_max_depth(&fs.camera);
    let poses: Vec<Vec<f64>> = depth_idx
        .iter()
        .map(|&i| {
            fs.frames[i]
                .scan_from_camera
                .to_homogeneous()
                .as_slice()
                .to_vec()
        })
        .collect();
    let key = CacheKey::new(
        "lift",
        1,
        &inputs,
        &json!({
            "views": depth_idx, "radius": radius, "image_size": image_size,
            "max_depth": max_depth, "poses": poses,
            "intrinsics": fs.camera.key(),
        }),
    )?;
    let links: Vec<Link> = ctx.stage(
        name,
        &key,
        |e| {
            let l: Vec<Link> = e.read_json("links.json")?;
            if l.len() != keypoints.len() {
                return Err(Error::Cache(format!(
                    "{}: {} links for {} keypoints",
                    e.dir.display(),
                    l.len(),
                    keypoints.len()
                )));
            }
            Ok(l)
        },
        || {
            // A view that repeats an earlier one (same depth bytes and pose: the frames of a
            // static f-theta camera) adds only ties, which go to the earlier view; skip it.
            let mut unique: Vec<usize> = Vec::new();
            for j in 0..depth_idx.len() {
                if !unique
                    .iter()
                    .any(|&u| hashes[u] == hashes[j] && poses[u] == poses[j])
                {
                    unique.push(j);
                }
            }
            let depths: Vec<crate::io::depth_png::DepthImage> = unique
                .par_iter()
                .map(|&j| crate::io::depth_png::read_depth_png(paths[j]))
                .collect::<Result<_>>()?;
            let views: Vec<LiftView> = depths
                .iter()
                .zip(&unique)
                .map(|(d, &j)| LiftView {
                    depth: d,
                    scan_from_camera: fs.frames[depth_idx[j]].scan_from_camera,
                    camera: &fs.camera,
                })
                .collect();
            let l = lift_views(&views, keypoints, radius, image_size, max_depth)?;
            Ok(l.into_iter()
                .map(|o| o.map(|p| (unique[p.view as usize] as u16, p.u, p.v)))
                .collect())
        },
        |l, c, k| {
            let mut ne = c.put(k, json!({ "stage": "lift" }))?;
            ne.add_json("links.json", l)?;
            ne.commit()?;
            Ok(())
        },
    )?;
    Ok((
        links
            .into_iter()
            .map(|o| o.map(|(view, u, v)| PixelLink { view, u, v }))
            .collect(),
        key,
    ))
}

/// Each keypoint's descriptor at its linked pixel (unit norm), zeros and invalid when unlinked.
fn point_descriptors(
    links: &[Option<PixelLink>],
    grids: &[DenseDescriptors],
) -> (Features, Vec<bool>) {
    let dim = grids.first().map_or(0, |g| g.dim);
    let mut data = vec![0.0f32; links.len() * dim];
    let mut valid = vec![false; links.len()];
    data.par_chunks_mut(dim.max(1))
        .zip(valid.par_iter_mut())
        .zip(links.par_iter())
        .for_each(|((row, ok), l)| {
            if let Some(l) = l {
                if let Some(g) = grids.get(l.view as usize) {
                    g.sample_into(l.u as f32, l.v as f32, row);
                    let n = row.iter().map(|v| v * v).sum::<f32>().sqrt();
                    if n > 1e-12 {
                        row.iter_mut().for_each(|v| *v /= n);
                        *ok = true;
                    }
                }
            }
        });
    (Features::new(dim, data), valid)
}

type Pts = (Features, Vec<bool>, Features, Vec<bool>);

/// Each keypoint's descriptor at its linked pixel of its view's grid (per-image models), cached.
fn per_image_point_features(
    ctx: &mut Ctx,
    lift_keys: (&CacheKey, &CacheKey),
    view_keys: (&[String], &[String]),
    links: (&[Option<PixelLink>], &[Option<PixelLink>]),
    grids: (&[DenseDescriptors], &[DenseDescriptors]),
) -> Result<Pts> {
    let (src_links, tgt_links) = links;
    let mut pk: Vec<&str> = vec![&lift_keys.0.hash, &lift_keys.1.hash];
    pk.extend(view_keys.0.iter().map(String::as_str));
    pk.extend(view_keys.1.iter().map(String::as_str));
    let pkey = CacheKey::new("image-points", 1, &pk, &json!({ "sample": "bilinear-l2" }))?;
    ctx.stage(
        "image point features",
        &pkey,
        |e| {
            let fs = e.read_features("source.npy")?;
            let ft = e.read_features("target.npy")?;
            let (vs, vt): (Vec<bool>, Vec<bool>) = e.read_json("valid.json")?;
            if fs.len() != src_links.len()
                || ft.len() != tgt_links.len()
                || vs.len() != fs.len()
                || vt.len() != ft.len()
            {
                return Err(Error::Cache(format!(
                    "{}: sizes disagree with the keypoints",
                    e.dir.display()
                )));
            }
            Ok((fs, vs, ft, vt))
        },
        || {
            let (fs, vs) = point_descriptors(src_links, grids.0);
            let (ft, vt) = point_descriptors(tgt_links, grids.1);
            Ok((fs, vs, ft, vt))
        },
        |(fs, vs, ft, vt), c, k| {
            let mut ne = c.put(k, json!({ "stage": "image-points" }))?;
            ne.add_features("source.npy", fs)?;
            ne.add_features("target.npy", ft)?;
            ne.add_json("valid.json", &(vs, vt))?;
            ne.commit()?;
            Ok(())
        },
    )
}

fn short_prompt(p: &crate::wfm::Prompt) -> String {
    let s = p.scene.trim();
    let mut out: String = s.chars().take(40).collect();
    if s.chars().count() > 40 {
        out.push('…');
    }
    if out.is_empty() {
        "(empty prompt)".into()
    } else {
        format!("\"{out}\"")
    }
}

/// The full method on one pair; `cache` None computes everything in memory.
pub fn register_with_image(
    pair: &ScanPair,
    params: &RegisterParams,
    ib: &ImageBranchParams,
    cache: Option<&Cache>,
) -> Result<RegistrationResult> {
    register_with_image_keep(pair, params, ib, cache, true).map(|(r, _)| r)
}

/// Start of the error returned by [`register_with_image_keep`] when `generate` is false and the
/// generation is not in the cache.
pub const GENERATION_NOT_CACHED: &str = "generation not cached";

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
    pub fn similarity(&self) -> Result<(crate::fusion::matrix::DenseMatrix, Vec<bool>, Vec<bool>)> {
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
    pub image: Option<(crate::fusion::matrix::DenseMatrix, Vec<bool>, Vec<bool>)>,
    pub geo: crate::fusion::matrix::DenseMatrix,
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

/// [`fuse_and_finish`] from similarities computed before (see [`similarities`]); the same
/// result, without the similarity stage.
pub fn fuse_and_finish_with(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: &Similarities,
) -> Result<RegistrationResult> {
    let mut timer = Timer::new();
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    if sims.image.is_some() {
        // kept in memory: shown as a hit, like the stage cache's entries
        timer.record("similarity", std::time::Duration::ZERO, true);
    }
    let t = Instant::now();
    let corr = match (&sims.image, &inputs.image) {
        (Some((s_img, vs, vt)), Some(_)) => {
            let c = match_then_fuse_select(Some((s_img, Some(vs), Some(vt))), Some(&sims.geo), &params.fusion)?;
            timer.record("fusion", t.elapsed(), false);
            c
        }
        (None, None) => {
            let mut fusion = params.fusion;
            fusion.mode = crate::fusion::FusionMode::GeometryOnly;
            let c = match (fusion.selection, fusion.calibration_geo) {
                (
                    crate::fusion::Selection::RowNn,
                    crate::fusion::Calibration::RowSoftmax { tau },
                ) => crate::fusion::streaming::row_nn_from_similarity(&sims.geo, tau)?,
                _ => match_then_fuse_select(None, Some(&sims.geo), &fusion)?,
            };
            timer.record("similarity+fusion", t.elapsed(), false);
            c
        }
        _ => {
            return Err(Error::Invalid(
                "kept similarities do not match the fusion inputs (image branch on one, off on the other)".into(),
            ))
        }
    };
    let label = inputs
        .image_label
        .as_ref()
        .map(|l| format!("{l}; fusion {:?})", params.fusion.mode));
    finish(pair, params, timer, src.clone(), tgt.clone(), corr, label)
}

/// Similarity, calibration, fusion, selection and estimation from kept [`FusionInputs`]; the
/// same computation as the tail of [`register_with_image`] (image branch present) or the
/// geometric-only registration (image None: geometry-only fusion, streaming row-NN when the
/// calibration allows it). `res.image` is left None: the caller re-attaches the views.
pub fn fuse_and_finish(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
) -> Result<RegistrationResult> {
    let mut timer = Timer::new();
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let corr = match &inputs.image {
        Some(image) => {
            let t = Instant::now();
            let (s_img, v_src, v_tgt) = image.similarity()?;
            let s_geo = cosine_similarity(&src.features, &tgt.features)?;
            timer.record("similarity", t.elapsed(), false);
            let t = Instant::now();
            // Same correspondences as `match_then_fuse`, without its N x M outputs.
            let corr = match_then_fuse_select(
                Some((&s_img, Some(&v_src), Some(&v_tgt))),
                Some(&s_geo),
                &params.fusion,
            )?;
            timer.record("fusion", t.elapsed(), false);
            corr
        }
        None => {
            let mut fusion = params.fusion;
            fusion.mode = crate::fusion::FusionMode::GeometryOnly;
            let t = Instant::now();
            let c = match (fusion.selection, fusion.calibration_geo) {
                (
                    crate::fusion::Selection::RowNn,
                    crate::fusion::Calibration::RowSoftmax { tau },
                ) => crate::fusion::streaming::row_nn_posterior(&src.features, &tgt.features, tau)?,
                _ => {
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
    finish(pair, params, timer, src.clone(), tgt.clone(), corr, label)
}

/// [`register_with_image`] that also returns the [`FusionInputs`]. With `generate` false a
/// generation missing from the cache is not produced: the call fails with an error starting
/// with [`GENERATION_NOT_CACHED`] (the GUI then offers to run the generator).
pub fn register_with_image_keep(
    pair: &ScanPair,
    params: &RegisterParams,
    ib: &ImageBranchParams,
    cache: Option<&Cache>,
    generate: bool,
) -> Result<(RegistrationResult, FusionInputs)> {
    // Point-cloud-only scans: render their depth frames from a virtual pinhole trajectory.
    if pair.source.frames.is_none() || pair.target.frames.is_none() {
        // Without a cache the frames go to a fresh scratch folder, removed when this call
        // returns (a fixed shared folder would leak files and mix concurrent runs).
        let scratch = match cache {
            Some(_) => None,
            None => Some(crate::io::limits::ScratchDir::new(
                "cgenreg-virtual-frames",
            )?),
        };
        let root = match (cache, &scratch) {
            (Some(c), _) => c.root().join("virtual-frames"),
            (None, Some(s)) => s.path().to_path_buf(),
            (None, None) => unreachable!("a scratch folder is made when there is no cache"),
        };
        let mut p2 = pair.clone();
        let mut notes = Vec::new();
        for scan in [&mut p2.source, &mut p2.target] {
            if scan.frames.is_none() {
                let cam = ib.virtual_camera.resolve(&scan.cloud);
                scan.frames = Some(render_virtual_frames_with(
                    scan,
                    ib.frames_per_fragment,
                    &root,
                    cam,
                    ib.lidar_cameras,
                )?);
                let note = match cam {
                    super::params::VirtualCamera::Ftheta if ib.lidar_cameras > 1 => format!(
                        "{VIRTUAL_FTHETA_NOTE}; {} such cameras, {:.0}° apart in yaw, shown one \
                         after the other in the depth video",
                        ib.lidar_cameras,
                        360.0 / ib.lidar_cameras as f64
                    ),
                    super::params::VirtualCamera::Ftheta => VIRTUAL_FTHETA_NOTE.to_string(),
                    _ => VIRTUAL_FRAMES_NOTE.to_string(),
                };
                if !notes.contains(&note) {
                    notes.push(note);
                }
            }
        }
        let (mut r, inputs) = register_with_image_keep(&p2, params, ib, cache, generate)?;
        r.warnings.extend(notes);
        // The views follow the reference's stride rule, not the cameras: say when some of
        // the f-theta cameras were never looked at.
        if ib.lidar_cameras > 1 {
            if let Some(img) = &r.image {
                for (side, views) in [("source", &img.source_views), ("target", &img.target_views)]
                {
                    let mut poses: Vec<[f64; 16]> = Vec::new();
                    for v in views.iter().filter(|v| v.camera.name() == "f-theta") {
                        let mut a = [0.0; 16];
                        if let Some(t) = v.scan_from_camera {
                            a.copy_from_slice(t.to_homogeneous().as_slice());
                        }
                        if !poses.contains(&a) {
                            poses.push(a);
                        }
                    }
                    if !views.is_empty() && poses.len() < ib.lidar_cameras.min(views.len()) {
                        r.warnings.push(format!(
                            "the {} selected {side} views see {} of the {} f-theta cameras \
                             (views follow the stride rule over L = {}, m = {}); raise K",
                            views.len(),
                            poses.len(),
                            ib.lidar_cameras,
                            ib.frames_per_fragment,
                            ib.margin
                        ));
                    }
                }
            }
        }
        return Ok((r, inputs));
    }
    if !matches!(params.geo_features, super::params::GeoFeatureSource::Fpfh) {
        return Err(Error::Invalid(
            "the image branch is wired to the FPFH geometric branch; learned geometric \
             features with the image branch are not supported yet"
                .into(),
        ));
    }
    let mut ctx = Ctx {
        cache,
        timer: Timer::new(),
        warnings: Vec::new(),
    };
    let l = ib.frames_per_fragment;
    let src_fs = frames_of(&pair.source, l)?;
    let tgt_fs = frames_of(&pair.target, l)?;
    // Fail early on bad K / m (before anything expensive).
    let sel = crate::wfm::select_views(2 * l, l, ib.margin, ib.k)?;
    let vfm_id = vfm_id(&ib.vfm)?;

    // Geometric branch (dense path: the image branch needs the N x M similarity).
    let (src_geo, src_geo_key) = geo_cached(&mut ctx, "fpfh source", &pair.source, params.voxel)?;
    let (tgt_geo, tgt_geo_key) = geo_cached(&mut ctx, "fpfh target", &pair.target, params.voxel)?;

    // Depth video.
    let src_paths: Vec<PathBuf> = src_fs.frames[..l]
        .iter()
        .map(|f| f.depth_path.clone())
        .collect();
    let tgt_paths: Vec<PathBuf> = tgt_fs.frames[..l]
        .iter()
        .map(|f| f.depth_path.clone())
        .collect();
    let t = Instant::now();
    let depth_hashes: Vec<String> = src_paths
        .par_iter()
        .chain(tgt_paths.par_iter())
        .map(|p| hash_file(p))
        .collect::<Result<_>>()?;
    let dh: Vec<&str> = depth_hashes.iter().map(String::as_str).collect();
    // One video, one clip: the larger of the two scans' (a LiDAR scan keeps its range).
    let lidar = [src_fs, tgt_fs]
        .iter()
        .any(|fs| matches!(fs.camera, crate::camera::CameraModel::FTheta(_)));
    let clip = depth_video_clip(&src_fs.camera).max(depth_video_clip(&tgt_fs.camera));
    let video_params = if lidar {
        json!({ "L": l, "clip": clip })
    } else {
        json!({ "L": l })
    };
    let video_key = CacheKey::new("depth-video", 1, &dh, &video_params)?;
    let mut video_frames: Option<Vec<RgbImage>> = None;
    let (vmeta, hit) = ctx.cached(
        &video_key,
        |e| e.read_json::<VideoMeta>("video.json"),
        || {
            let frames =
                crate::wfm::depth_video::pair_video_from_files_clip(&src_paths, &tgt_paths, clip)?;
            let mut h = blake3::Hasher::new();
            for f in &frames {
                h.update(&f.width().to_le_bytes());
                h.update(&f.height().to_le_bytes());
                h.update(f.as_raw());
            }
            let m = VideoMeta {
                hash: h.finalize().to_hex().to_string(),
                frames: frames.len(),
                width: frames.first().map_or(0, |f| f.width()),
                height: frames.first().map_or(0, |f| f.height()),
            };
            video_frames = Some(frames);
            Ok(m)
        },
        |m, c, k| {
            let mut ne = c.put(
                k,
                json!({ "L": l, "source": pair.source.name, "target": pair.target.name }),
            )?;
            ne.add_json("video.json", m)?;
            ne.commit()?;
            Ok(())
        },
    )?;
    ctx.timer.record("depth video", t.elapsed(), hit);

    // Generation.
    let backend = make_backend(&ib.backend, lidar)?;
    let backend_id = backend.id();
    let is_oracle = matches!(ib.backend, WfmSpec::Oracle);
    let colour = |fs: &FrameSet| -> Option<Vec<PathBuf>> {
        fs.frames[..l]
            .iter()
            .map(|f| f.color_path.clone())
            .collect()
    };
    let (src_col, tgt_col) = (colour(src_fs), colour(tgt_fs));
    let mut gen_inputs = vec![vmeta.hash.clone()];
    if is_oracle {
        // The oracle's output is the colour frames, so they (not the depth) key it.
        let (Some(s), Some(t)) = (&src_col, &tgt_col) else {
            return Err(Error::Invalid(format!(
                "oracle backend: pair `{}` has no colour frames",
                pair.id
            )));
        };
        let h: Vec<String> = s
            .par_iter()
            .chain(t.par_iter())
            .map(|p| hash_file(p))
            .collect::<Result<_>>()?;
        gen_inputs.extend(h);
    }
    let gi: Vec<&str> = gen_inputs.iter().map(String::as_str).collect();
    let prompt_text = ib.prompt.text();
    let gen_key = CacheKey::new(
        "generation",
        1,
        &gi,
        &json!({ "backend": backend_id, "prompt": prompt_text, "seed": ib.seed }),
    )?;
    let t = Instant::now();
    let (gen, hit) = ctx.cached(
        &gen_key,
        |e| {
            let provenance: Provenance = e.read_json("provenance.json")?;
            let meta: GenMeta = e.read_json("meta.json")?;
            if (0..meta.frames).any(|i| !e.manifest.files.iter().any(|f| f.name == frame_name(i))) {
                return Err(Error::Cache(format!("{}: frames missing", e.dir.display())));
            }
            Ok(GenOut {
                provenance,
                meta,
                frames: None,
                entry: Some(e.clone()),
            })
        },
        || {
            if !generate {
                return Err(Error::Invalid(format!(
                    "{GENERATION_NOT_CACHED}: {backend_id}, prompt {}, seed {}",
                    short_prompt(&ib.prompt),
                    ib.seed
                )));
            }
            let depth_video = match video_frames.take() {
                Some(f) => f,
                None if is_oracle => Vec::new(),
                None => crate::wfm::depth_video::pair_video_from_files_clip(
                    &src_paths, &tgt_paths, clip,
                )?,
            };
            let req = GenerateRequest {
                pair_id: pair.id.clone(),
                depth_video,
                depth_video_path: None,
                prompt: ib.prompt.clone(),
                seed: ib.seed,
                source_color: src_col.clone(),
                target_color: tgt_col.clone(),
            };
            let g = backend.generate(&req)?;
            if g.frames.len() < 2 * l {
                return Err(Error::External {
                    what: backend_id.clone(),
                    message: format!("returned {} frames, {} needed", g.frames.len(), 2 * l),
                });
            }
            let (w, h) = g.frames[0].dimensions();
            if g.frames.iter().any(|f| f.dimensions() != (w, h)) {
                return Err(Error::External {
                    what: backend_id.clone(),
                    message: "frames of different sizes".into(),
                });
            }
            Ok(GenOut {
                meta: GenMeta {
                    frames: g.frames.len(),
                    width: w,
                    height: h,
                },
                provenance: g.provenance,
                frames: Some(g.frames),
                entry: None,
            })
        },
        |g, c, k| {
            let frames = g
                .frames
                .as_ref()
                .ok_or_else(|| Error::Invalid("no frames".into()))?;
            let pngs: Vec<Vec<u8>> = frames
                .par_iter()
                .map(encode_png_fast)
                .collect::<Result<_>>()?;
            let prov = serde_json::to_value(&g.provenance)
                .map_err(|e| Error::Invalid(format!("provenance: {e}")))?;
            let mut ne = c.put(k, prov)?;
            for (i, b) in pngs.iter().enumerate() {
                ne.add_bytes(&frame_name(i), b)?;
            }
            ne.add_json("provenance.json", &g.provenance)?;
            ne.add_json("meta.json", &g.meta)?;
            ne.commit()?;
            Ok(())
        },
    )?;
    ctx.timer.record("generation", t.elapsed(), hit);
    let image_size = (gen.meta.width, gen.meta.height);

    // View selection on the actual video length.
    let t = Instant::now();
    let sel = if gen.meta.frames == 2 * l {
        sel
    } else {
        crate::wfm::select_views(gen.meta.frames, l, ib.margin, ib.k)?
    };
    ctx.timer.record("view selection", t.elapsed(), false);

    // VFM descriptors per selected view.
    let mut model: Option<Arc<dyn PerImageModel>> = None;
    let mut describe_side = |ctx: &mut Ctx,
                             name: &str,
                             idx: &[usize]|
     -> Result<(Vec<DenseDescriptors>, Vec<RgbImage>, Vec<String>)> {
        let t = Instant::now();
        let mut all_hit = true;
        let mut grids = Vec::new();
        let mut images = Vec::new();
        let mut keys = Vec::new();
        for &gi in idx {
            let img = gen.frame(gi)?;
            let key = CacheKey::new(
                "vfm-view",
                1,
                &[&gen_key.hash],
                &json!({ "frame": gi, "vfm": vfm_id }),
            )?;
            let (g, hit) = ctx.cached(
                &key,
                |e| {
                    let m: GridMeta = e.read_json("grid.json")?;
                    let (_, _, d) = e.read_f32_matrix("desc.npy")?;
                    DenseDescriptors::new(m.width, m.height, m.dim, d, m.stride_x, m.stride_y)
                },
                || {
                    if model.is_none() {
                        model = Some(load_vfm(&ib.vfm)?);
                    }
                    match &model {
                        Some(m) => m.describe(&img),
                        None => Err(Error::Invalid("VFM not loaded".into())),
                    }
                },
                |g, c, k| {
                    let mut ne = c.put(k, json!({ "vfm": vfm_id, "frame": gi }))?;
                    ne.add_json(
                        "grid.json",
                        &GridMeta {
                            width: g.width,
                            height: g.height,
                            dim: g.dim,
                            stride_x: g.stride_x,
                            stride_y: g.stride_y,
                        },
                    )?;
                    ne.add_f32_matrix("desc.npy", (g.width * g.height) as usize, g.dim, &g.data)?;
                    ne.commit()?;
                    Ok(())
                },
            )?;
            all_hit &= hit;
            grids.push(g);
            images.push(img);
            keys.push(key.hash);
        }
        ctx.timer.record(name, t.elapsed(), all_hit);
        Ok((grids, images, keys))
    };
    let pair_conditioned = matches!(ib.vfm, VfmSpec::Mast3r { .. });
    let ((src_grids, src_imgs, src_vkeys), (tgt_grids, tgt_imgs, tgt_vkeys)) = if pair_conditioned {
        // Pair models describe views jointly: only the images here; descriptors below.
        let imgs = |idx: &[usize]| -> Result<Vec<RgbImage>> {
            idx.iter().map(|&gi| gen.frame(gi)).collect()
        };
        (
            (Vec::new(), imgs(&sel.src_generated)?, Vec::new()),
            (Vec::new(), imgs(&sel.tgt_generated)?, Vec::new()),
        )
    } else {
        (
            describe_side(&mut ctx, "vfm source views", &sel.src_generated)?,
            describe_side(&mut ctx, "vfm target views", &sel.tgt_generated)?,
        )
    };
    let mut vfm_label = match &model {
        Some(_) => format!("{vfm_id} ({})", crate::vfm::backend_name()),
        None => format!("{vfm_id} (descriptors from the cache)"),
    };

    // Lifting, over all K views, radius 5 cm.
    let (src_links, src_lift_key) = lift_stage(
        &mut ctx,
        "lift source",
        &src_geo_key,
        &src_geo.keypoints.points,
        src_fs,
        &sel.src_depth,
        ib.lift_radius,
        image_size,
    )?;
    let (tgt_links, tgt_lift_key) = lift_stage(
        &mut ctx,
        "lift target",
        &tgt_geo_key,
        &tgt_geo.keypoints.points,
        tgt_fs,
        &sel.tgt_depth,
        ib.lift_radius,
        image_size,
    )?;

    // Per-keypoint image descriptors (per-image models) or per-pair descriptors (pair models).
    let image_inputs: ImageInputs = if pair_conditioned {
        let mut pk: Vec<&str> = vec![&src_lift_key.hash, &tgt_lift_key.hash, &gen_key.hash];
        pk.push(&vfm_id);
        let pkey = CacheKey::new(
            "image-points-pair",
            1,
            &pk,
            &json!({ "src_frames": sel.src_generated, "tgt_frames": sel.tgt_generated,
                     "sample": "bilinear-l2" }),
        )?;
        let (k_src, k_tgt) = (src_imgs.len(), tgt_imgs.len());
        let mut loaded = false;
        let d: PairPointDescriptors = ctx.stage(
            "vfm view pairs + point features",
            &pkey,
            |e| {
                let (ns, cs, src) = e.read_f32_matrix("source.npy")?;
                let (nt, ct, tgt) = e.read_f32_matrix("target.npy")?;
                let (src_view, tgt_view): (Vec<Option<u16>>, Vec<Option<u16>>) =
                    e.read_json("views.json")?;
                let dim = cs / k_tgt.max(1);
                if ns != src_links.len()
                    || nt != tgt_links.len()
                    || src_view.len() != ns
                    || tgt_view.len() != nt
                    || cs != dim * k_tgt
                    || ct != dim * k_src
                {
                    return Err(Error::Cache(format!(
                        "{}: sizes disagree with the keypoints and views",
                        e.dir.display()
                    )));
                }
                Ok(PairPointDescriptors {
                    k_src,
                    k_tgt,
                    dim,
                    src,
                    src_view,
                    tgt,
                    tgt_view,
                })
            },
            || {
                let m = load_pair_vfm(&ib.vfm)?;
                loaded = true;
                let pairs = crate::vfm::describe_all_pairs(m.as_ref(), &src_imgs, &tgt_imgs)?;
                pair_point_descriptors(&pairs, k_src, k_tgt, &src_links, &tgt_links)
            },
            |d, c, k| {
                let mut ne = c.put(k, json!({ "stage": "image-points-pair", "vfm": vfm_id }))?;
                ne.add_f32_matrix("source.npy", d.src_view.len(), d.k_tgt * d.dim, &d.src)?;
                ne.add_f32_matrix("target.npy", d.tgt_view.len(), d.k_src * d.dim, &d.tgt)?;
                ne.add_json("views.json", &(&d.src_view, &d.tgt_view))?;
                ne.commit()?;
                Ok(())
            },
        )?;
        vfm_label = if loaded {
            format!(
                "{vfm_id} ({}; {}x{} view pairs)",
                crate::vfm::backend_name(),
                k_src,
                k_tgt
            )
        } else {
            format!("{vfm_id} (pair descriptors from the cache)")
        };
        ImageInputs::PairConditioned(d)
    } else {
        let (f_src, v_src, f_tgt, v_tgt) = per_image_point_features(
            &mut ctx,
            (&src_lift_key, &tgt_lift_key),
            (&src_vkeys, &tgt_vkeys),
            (&src_links, &tgt_links),
            (&src_grids, &tgt_grids),
        )?;
        ImageInputs::PerImage(f_src, v_src, f_tgt, v_tgt)
    };
    let (v_src, v_tgt) = image_inputs.validity();

    let n_valid = (
        v_src.iter().filter(|v| **v).count(),
        v_tgt.iter().filter(|v| **v).count(),
    );
    let label = format!(
        "{} + {} (K={}, m={}, L={}; {} / {} source / target keypoints with a pixel",
        gen.provenance.backend, vfm_id, ib.k, ib.margin, l, n_valid.0, n_valid.1,
    );
    let view_label = format!(
        "{} | {} | cache {}",
        gen.provenance.backend,
        short_prompt(&ib.prompt),
        &gen_key.hash[..8]
    );
    let views = |imgs: Vec<RgbImage>,
                 gen_idx: &[usize],
                 depth_idx: &[usize],
                 fs: &FrameSet|
     -> Vec<ViewInfo> {
        imgs.into_iter()
            .zip(gen_idx.iter().zip(depth_idx))
            .map(|(image, (&g, &d))| ViewInfo {
                image,
                generated_index: g,
                depth_index: d,
                label: view_label.clone(),
                depth_path: fs.frames.get(d).map(|f| f.depth_path.clone()),
                scan_from_camera: fs.frames.get(d).map(|f| f.scan_from_camera),
                camera: fs.camera.clone(),
            })
            .collect()
    };
    let output = ImageBranchOutput {
        source_views: views(src_imgs, &sel.src_generated, &sel.src_depth, src_fs),
        target_views: views(tgt_imgs, &sel.tgt_generated, &sel.tgt_depth, tgt_fs),
        source_links: src_links,
        target_links: tgt_links,
        provenance: gen.provenance.clone(),
        vfm: vfm_label,
    };
    let Ctx {
        timer, warnings, ..
    } = ctx;
    let inputs = FusionInputs {
        source_geo: src_geo,
        target_geo: tgt_geo,
        image: Some(image_inputs),
        image_label: Some(label),
    };
    let mut res = fuse_and_finish(pair, params, &inputs)?;
    // The cached stages' timings first, then the in-memory ones.
    let mut timings = timer.timings;
    timings.append(&mut res.timings);
    res.timings = timings;
    res.total_ms = timer.t0.elapsed().as_secs_f64() * 1e3;
    res.warnings.extend(warnings);
    res.warnings.extend(gen.provenance.warnings.iter().cloned());
    res.image = Some(output);
    Ok((res, inputs))
}

/// Said with every result whose depth frames were rendered, not sensed.
pub const VIRTUAL_FRAMES_NOTE: &str = "depth frames rendered from a virtual pinhole trajectory \
(the scan had no sensor frames): 640x480, fx = fy = 585, 30° sweep, half the fit-to-view distance";

/// Largest ring gap (pixels, vertical) closed in f-theta range images.
const FTHETA_RING_GAP_PX: u32 = 24;

/// Said with every result whose depth frames come from the virtual f-theta camera.
pub const VIRTUAL_FTHETA_NOTE: &str = "depth frames rendered from a virtual f-theta camera \
(LiDAR, appendix B.3): 1280x640, equidistant, 180° horizontal field of view, at the scan's \
origin looking along +x (the sensor is assumed at the origin); range in the depth frames, \
no 4 m clip; gaps of up to 24 px between LiDAR rings on one surface filled by interpolation";

/// Depth frames for a point-cloud-only scan from the chosen virtual camera: the pinhole
/// trajectory of [`render_virtual_frames`], or for LiDAR f-theta cameras at the sensor origin:
/// one facing forward by default (the paper's Waymo setup: "a single forward-facing virtual
/// camera"), or `cameras` evenly spaced in yaw to cover a 360° scan (appendix B.3). A camera
/// does not move, so its one range image stands for its run of the `l` frames (frame i shows
/// camera floor(i * cameras / l)).
pub fn render_virtual_frames_with(
    scan: &Scan,
    l: usize,
    root: &Path,
    camera: super::params::VirtualCamera,
    cameras: usize,
) -> Result<FrameSet> {
    use crate::camera::ftheta::{lidar_front_camera_from_scan, FThetaCamera};
    if camera.resolve(&scan.cloud) != super::params::VirtualCamera::Ftheta {
        return render_virtual_frames(scan, l, root);
    }
    if l == 0 || cameras == 0 || cameras > l {
        return Err(Error::Invalid(format!(
            "virtual f-theta frames: {cameras} cameras for L = {l} frames; need 1 <= cameras <= L"
        )));
    }
    let cam = FThetaCamera::default();
    let mut paths = Vec::with_capacity(cameras);
    let mut poses = Vec::with_capacity(cameras);
    for c in 0..cameras {
        let yaw = std::f64::consts::TAU * c as f64 / cameras as f64;
        let camera_from_scan = lidar_front_camera_from_scan(yaw);
        // With one camera an empty image means the scan is not in its sensor frame; with
        // several, a camera facing away from a partial scan may see nothing.
        paths.push(ftheta_range_image(
            scan,
            &cam,
            &camera_from_scan,
            root,
            cameras == 1,
        )?);
        poses.push(camera_from_scan.inverse());
    }
    Ok(FrameSet {
        camera: crate::camera::CameraModel::FTheta(cam),
        frames: (0..l)
            .map(|i| {
                let c = i * cameras / l;
                crate::dataset::RgbdFrame {
                    index: i,
                    depth_path: paths[c].clone(),
                    color_path: None,
                    scan_from_camera: poses[c],
                }
            })
            .collect(),
    })
}

/// One f-theta range image of `scan` seen with pose `camera_from_scan`, cached under `root`
/// by content; returns its path.
fn ftheta_range_image(
    scan: &Scan,
    cam: &crate::camera::ftheta::FThetaCamera,
    camera_from_scan: &Isometry3<f64>,
    root: &Path,
    empty_is_error: bool,
) -> Result<PathBuf> {
    let key = blake3::hash(
        format!(
            "virtual-ftheta-v2|gap{FTHETA_RING_GAP_PX}|{}|{:?}|{:?}",
            cloud_hash(&scan.cloud),
            cam,
            camera_from_scan.to_homogeneous().as_slice()
        )
        .as_bytes(),
    )
    .to_hex()
    .to_string();
    let dir = root.join(&key[..32]);
    let path = dir.join("range.depth.png");
    if !path.is_file() {
        let mut d = cam.render_depth(
            &scan.cloud.points,
            camera_from_scan,
            &crate::camera::render::SplatOptions::default(),
        );
        // Rings of a spinning LiDAR are a few degrees apart: about 2-20 px at 1280x640.
        crate::camera::ftheta::fill_ring_gaps(&mut d, FTHETA_RING_GAP_PX, 0.1);
        if empty_is_error && d.data.iter().all(|&v| v == 0) {
            return Err(Error::Invalid(format!(
                "{}: no point is in view of the virtual f-theta camera (at the origin, looking \
                 along +x); is this a LiDAR scan in its sensor frame?",
                scan.name
            )));
        }
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        // write_depth_png is atomic: the file exists only once complete.
        crate::io::depth_png::write_depth_png(&path, &d)?;
    }
    Ok(path)
}

/// Depth frames of a point-cloud-only scan: `l` views along a virtual pinhole arc around the
/// cloud ([`crate::camera::trajectory::virtual_trajectory`], default options: OpenCV axes with
/// y down), z-buffered splats written as 16-bit millimetre PNGs under `root/<hash>/`, where the
/// hash covers the points and the frame count. The folder is complete once `poses.json` is
/// there (written last), so an interrupted run is redone, never half-used.
pub fn render_virtual_frames(scan: &Scan, l: usize, root: &Path) -> Result<FrameSet> {
    use crate::camera::trajectory::{virtual_trajectory, TrajectoryOptions};
    // Half the automatic distance: the scan over-fills the view, but its depths stay mostly
    // inside the depth video's 4 m clip (reference §1.2) instead of all beyond it.
    let opts = TrajectoryOptions {
        distance_scale: 0.5,
        ..Default::default()
    };
    let key = blake3::hash(
        format!(
            "virtual-frames-v1|{}|{l}|{:?}",
            cloud_hash(&scan.cloud),
            opts
        )
        .as_bytes(),
    )
    .to_hex()
    .to_string();
    let dir = root.join(&key[..32]);
    let poses_file = dir.join("poses.json");
    let name = |i: usize| dir.join(format!("frame-{i:06}.depth.png"));
    let poses: Vec<Isometry3<f64>> = match std::fs::read(&poses_file)
        .ok()
        .and_then(|b| serde_json::from_slice::<Vec<[f64; 16]>>(&b).ok())
    {
        Some(m) if m.len() == l && (0..l).all(|i| name(i).is_file()) => m
            .iter()
            .map(|a| {
                crate::geometry::transform::isometry_from_matrix(
                    &nalgebra::Matrix4::from_column_slice(a),
                )
                .ok_or_else(|| {
                    Error::format(&poses_file, "poses", "rigid 4x4 matrices", "not rigid")
                })
            })
            .collect::<Result<_>>()?,
        _ => {
            let poses = virtual_trajectory(&scan.cloud, l, &opts)?;
            std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            poses
                .par_iter()
                .enumerate()
                .try_for_each(|(i, scan_from_camera)| {
                    let d = crate::camera::render::render_depth(
                        &scan.cloud.points,
                        &opts.intrinsics,
                        &scan_from_camera.inverse(),
                    );
                    crate::io::depth_png::write_depth_png(&name(i), &d)
                })?;
            let m: Vec<[f64; 16]> = poses
                .iter()
                .map(|p| {
                    let mut a = [0.0; 16];
                    a.copy_from_slice(p.to_homogeneous().as_slice());
                    a
                })
                .collect();
            let bytes = serde_json::to_vec(&m)
                .map_err(|e| Error::Invalid(format!("virtual poses: {e}")))?;
            crate::error::write_atomic(&poses_file, &bytes)?;
            poses
        }
    };
    Ok(FrameSet {
        camera: opts.intrinsics.into(),
        frames: poses
            .into_iter()
            .enumerate()
            .map(|(i, scan_from_camera)| crate::dataset::RgbdFrame {
                index: i,
                depth_path: name(i),
                color_path: None,
                scan_from_camera,
            })
            .collect(),
    })
}

/// The default cache directory: `$CGENREG_CACHE`, else `~/.cache/cgenreg`.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("CGENREG_CACHE").filter(|d| !d.is_empty()) {
        return PathBuf::from(d);
    }
    match std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        Some(h) => PathBuf::from(h).join(".cache").join("cgenreg"),
        None => PathBuf::from(".cgenreg-cache"),
    }
}

/// `status_word` for callers that count hits.
pub fn is_cached(status: &str) -> bool {
    status == status_word(true)
}
