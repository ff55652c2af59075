//! Stage `lift`: the pixel link of each keypoint of one scan in its K selected views
//! (reference §4: back-projection within a radius, depth clip 5 m). Key: the scan's
//! `geo-fpfh` key and the selected depth files' content hashes; parameters: the view indices,
//! radius, image size, depth clip, the views' poses and the camera model.

use super::depth_video::LIDAR_MAX_RANGE;
use super::Ctx;
use crate::cache::{Cache, CacheKey, Entry};
use crate::camera::CameraModel;
use crate::camera::DepthView;
use crate::dataset::FrameSet;
use crate::error::{Error, Result};
use crate::pipeline::graph::StageName;
use crate::pipeline::memo::Memo;
use crate::pipeline::params::{ImageBranchParams, RegisterParams};
use crate::vfm::lift::{lift_views, PixelLink};
use nalgebra::Point3;
use rayon::prelude::*;
use serde_json::json;
use std::path::Path;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: StageName = StageName::Lift;

/// What the stage reads of the settings: the lift radius (m) at the keypoints' voxel (0 when
/// the image branch is off: the stage does not run then).
pub fn settings(p: &RegisterParams) -> f32 {
    let RegisterParams {
        voxel,
        geo_features: _,
        fusion: _,
        estimator: _,
        inlier_threshold: _,
        image,
        success: _,
        // each scale hypothesis is a registration at one voxel
        scales: _,
    } = p;
    let Some(ib) = image else {
        return 0.0;
    };
    let ImageBranchParams {
        backend: _,
        prompt: _,
        seed: _,
        vfm: _,
        // the views (K, m, L) reach the key as the selected depth frames
        k: _,
        margin: _,
        frames_per_fragment: _,
        lift_radius,
        virtual_camera: _,
        lidar_cameras: _,
        lidar_origin: _,
        dense_stride: _,
    } = ib;
    lift_radius.at(*voxel, crate::estimate::scale::LIFT_RADIUS_PER_VOXEL)
}

/// Depth clip used when lifting (reference §4: 5 m).
const LIFT_MAX_DEPTH: f32 = 5.0;

/// Lifting clip for frames of `camera`.
fn lift_max_depth(camera: &CameraModel) -> f32 {
    match camera {
        CameraModel::Pinhole(_) => LIFT_MAX_DEPTH,
        CameraModel::FTheta(_) => LIDAR_MAX_RANGE,
    }
}

/// (view, u, v) as stored.
type Link = Option<(u16, u32, u32)>;

/// What the lift of one scan reads: its keypoints (and their stage key), its frames and
/// the selected depth frames.
pub(crate) struct LiftInput<'a> {
    pub(crate) geo_key: &'a CacheKey,
    pub(crate) keypoints: &'a [Point3<f32>],
    pub(crate) frames: &'a FrameSet,
    pub(crate) depth_idx: &'a [usize],
}

/// The views' poses as the key records them (column-major 4x4).
fn poses(inp: &LiftInput) -> Vec<Vec<f64>> {
    inp.depth_idx
        .iter()
        .map(|&i| {
            inp.frames.frames[i]
                .scan_from_camera
                .to_homogeneous()
                .as_slice()
                .to_vec()
        })
        .collect()
}

pub fn key(
    geo_key: &CacheKey,
    depth_hashes: &[String],
    depth_idx: &[usize],
    radius: f32,
    image_size: (u32, u32),
    poses: &[Vec<f64>],
    frames: &FrameSet,
) -> Result<CacheKey> {
    let mut inputs: Vec<&str> = vec![geo_key.hash.as_str()];
    inputs.extend(depth_hashes.iter().map(String::as_str));
    CacheKey::new(
        STAGE,
        VERSION,
        &inputs,
        &json!({
            "views": depth_idx, "radius": radius, "image_size": image_size,
            "max_depth": lift_max_depth(&frames.camera), "poses": poses,
            "intrinsics": frames.camera.key(),
        }),
    )
}

fn load(e: &Entry, n_keypoints: usize) -> Result<Vec<Link>> {
    let l: Vec<Link> = e.read_json("links.json")?;
    if l.len() != n_keypoints {
        return Err(Error::Cache(format!(
            "{}: {} links for {} keypoints",
            e.dir.display(),
            l.len(),
            n_keypoints
        )));
    }
    Ok(l)
}

fn store(l: &[Link], c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(k, json!({ "stage": STAGE }))?;
    ne.add_json("links.json", l)?;
    ne.commit()?;
    Ok(())
}

fn compute(
    inp: &LiftInput,
    paths: &[&Path],
    hashes: &[String],
    poses: &[Vec<f64>],
    radius: f32,
    image_size: (u32, u32),
) -> Result<Vec<Link>> {
    // A view that repeats an earlier one (same depth bytes and pose: the frames of a
    // static f-theta camera) adds only ties, which go to the earlier view; skip it.
    let mut unique: Vec<usize> = Vec::new();
    for j in 0..inp.depth_idx.len() {
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
    let fs = inp.frames;
    let views: Vec<DepthView> = depths
        .iter()
        .zip(&unique)
        .map(|(d, &j)| DepthView {
            depth: d,
            scan_from_camera: fs.frames[inp.depth_idx[j]].scan_from_camera,
            camera: &fs.camera,
        })
        .collect();
    let max_depth = lift_max_depth(&fs.camera);
    let l = lift_views(&views, inp.keypoints, radius, image_size, max_depth)?;
    Ok(l.into_iter()
        .map(|o| o.map(|p| (unique[p.view as usize] as u16, p.u, p.v)))
        .collect())
}

/// The selected depth files, their content hashes, the views' poses and the stage key.
type Prepared<'a> = (Vec<&'a Path>, Vec<String>, Vec<Vec<f64>>, CacheKey);

fn prepare<'a>(
    memo: &Memo,
    inp: &LiftInput<'a>,
    radius: f32,
    image_size: (u32, u32),
) -> Result<Prepared<'a>> {
    let paths: Vec<&Path> = inp
        .depth_idx
        .iter()
        .map(|&i| {
            inp.frames
                .frames
                .get(i)
                .map(|f| f.depth_path.as_path())
                .ok_or_else(|| Error::Shape(format!("depth frame {i} out of range")))
        })
        .collect::<Result<_>>()?;
    let hashes: Vec<String> = paths
        .par_iter()
        .map(|p| memo.hash_file(p))
        .collect::<Result<_>>()?;
    let poses = poses(inp);
    let key = key(
        inp.geo_key,
        &hashes,
        inp.depth_idx,
        radius,
        image_size,
        &poses,
        inp.frames,
    )?;
    Ok((paths, hashes, poses, key))
}

/// The stage key of `inp`'s lift (hashes the selected depth files; the keypoints are not read).
pub(crate) fn key_for(
    memo: &Memo,
    inp: &LiftInput,
    radius: f32,
    image_size: (u32, u32),
) -> Result<CacheKey> {
    prepare(memo, inp, radius, image_size).map(|p| p.3)
}

/// The keypoints' pixel links, timed as `label`; with the stage key (image points chain it).
pub(crate) fn run(
    ctx: &mut Ctx,
    label: &str,
    inp: &LiftInput,
    radius: f32,
    image_size: (u32, u32),
) -> Result<(Vec<Option<PixelLink>>, CacheKey)> {
    let (paths, hashes, poses, key) = prepare(ctx.memo, inp, radius, image_size)?;
    let links = ctx.stage(
        NAME,
        label,
        &key,
        |e| load(e, inp.keypoints.len()),
        || compute(inp, &paths, &hashes, &poses, radius, image_size),
        |l, c, k| store(l, c, k),
    )?;
    Ok((
        links
            .into_iter()
            .map(|o| o.map(|(view, u, v)| PixelLink { view, u, v }))
            .collect(),
        key,
    ))
}
