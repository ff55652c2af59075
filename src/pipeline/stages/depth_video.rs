//! Stage `depth-video`: the pair's depth video (reference §1: the first L depth frames of
//! the source, then of the target, clipped and colour-mapped). Key: the content hashes of
//! those 2L depth files; parameters: L, and the clip for LiDAR pairs. The entry holds the
//! hash of the encoded frames only: the frames are rebuilt in memory when generation misses.

use super::Ctx;
use crate::cache::{Cache, CacheKey};
use crate::camera::CameraModel;
use crate::dataset::{FrameSet, Scan, ScanPair};
use crate::error::{Error, Result};
use crate::pipeline::memo::Memo;
use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::DepthVideo;

/// What the stage reads of the settings: L, the frames per fragment.
pub fn settings(ib: &crate::pipeline::params::ImageBranchParams) -> usize {
    use crate::pipeline::params::ImageBranchParams;
    let ImageBranchParams {
        backend: _,
        prompt: _,
        seed: _,
        vfm: _,
        k: _,
        margin: _,
        frames_per_fragment,
        lift_radius: _,
        // the virtual frames' depth files (inputs) carry these
        virtual_camera: _,
        lidar_cameras: _,
        lidar_origin: _,
        dense_stride: _,
    } = ib;
    *frames_per_fragment
}

/// Range limit for f-theta (LiDAR) frames, in lifting and in the depth video: the reference's
/// indoor clips (5 m, 4 m) would flatten a LiDAR scan, so only the 16-bit millimetre range of
/// the depth PNGs limits them.
pub(crate) const LIDAR_MAX_RANGE: f32 = 65.0;

/// Depth-video clip (metres) for frames of `camera`: the reference's 4 m for RGB-D frames,
/// the whole range for LiDAR (f-theta) frames. The GUI shows depth frames with the same clip.
pub fn depth_video_clip(camera: &CameraModel) -> f64 {
    match camera {
        CameraModel::Pinhole(_) => crate::wfm::depth_video::CLIP_METERS,
        CameraModel::FTheta(_) => LIDAR_MAX_RANGE as f64,
    }
}

/// Whether either scan is a LiDAR (f-theta) scan, and the pair's depth clip: one video, one
/// clip, the larger of the two scans' (a LiDAR scan keeps its range).
pub(crate) fn pair_clip(src_fs: &FrameSet, tgt_fs: &FrameSet) -> (bool, f64) {
    let lidar = [src_fs, tgt_fs]
        .iter()
        .any(|fs| matches!(fs.camera, CameraModel::FTheta(_)));
    let clip = depth_video_clip(&src_fs.camera).max(depth_video_clip(&tgt_fs.camera));
    (lidar, clip)
}

/// The scan's frames, at least `l` of them.
pub(crate) fn frames_of(scan: &Scan, l: usize) -> Result<&FrameSet> {
    let fs = scan.frames.as_ref().ok_or_else(|| {
        Error::Missing(format!(
            "{}: the image branch needs the RGB-D frames the scan was made from (a raw-sequence \
             fragment, or a cloud with `frames` in the manifest)",
            scan.name
        ))
    })?;
    if fs.frames.len() < l {
        return Err(Error::Param(format!(
            "{}: {} frames, but the depth video needs L = {l} per fragment (set \
             frames_per_fragment / --frames)",
            scan.name,
            fs.frames.len()
        )));
    }
    Ok(fs)
}

#[derive(Serialize, Deserialize)]
pub(crate) struct VideoMeta {
    /// blake3 of the frames' sizes and pixels: the generation's input key.
    pub(crate) hash: String,
    frames: usize,
    width: u32,
    height: u32,
}

/// The depth video of a pair: its hash always, its frames when they were just built.
pub(crate) struct DepthVideo {
    /// The stage's key hash.
    pub(crate) key: String,
    pub(crate) meta: VideoMeta,
    frames: Option<Vec<RgbImage>>,
    src_paths: Vec<PathBuf>,
    tgt_paths: Vec<PathBuf>,
    clip: f64,
    /// Either scan is a LiDAR (f-theta) scan.
    pub(crate) lidar: bool,
}

impl DepthVideo {
    /// The frames (built now when the stage was a cache hit).
    pub(crate) fn take_frames(&mut self) -> Result<Vec<RgbImage>> {
        match self.frames.take() {
            Some(f) => Ok(f),
            None => build(&self.src_paths, &self.tgt_paths, self.clip),
        }
    }

    /// Whether the frames are in memory.
    pub(crate) fn has_frames(&self) -> bool {
        self.frames.is_some()
    }
}

fn build(src: &[PathBuf], tgt: &[PathBuf], clip: f64) -> Result<Vec<RgbImage>> {
    crate::wfm::depth_video::pair_video_from_files_clip(src, tgt, clip)
}

fn meta_of(frames: &[RgbImage]) -> VideoMeta {
    let mut h = blake3::Hasher::new();
    for f in frames {
        h.update(&f.width().to_le_bytes());
        h.update(&f.height().to_le_bytes());
        h.update(f.as_raw());
    }
    VideoMeta {
        hash: h.finalize().to_hex().to_string(),
        frames: frames.len(),
        width: frames.first().map_or(0, |f| f.width()),
        height: frames.first().map_or(0, |f| f.height()),
    }
}

/// Key from the depth files' hashes, L and the clip (LiDAR pairs only: the indoor key is
/// unchanged since before the clip existed).
pub fn key(depth_hashes: &[String], l: usize, lidar: bool, clip: f64) -> Result<CacheKey> {
    let dh: Vec<&str> = depth_hashes.iter().map(String::as_str).collect();
    let params = if lidar {
        json!({ "L": l, "clip": clip })
    } else {
        json!({ "L": l })
    };
    CacheKey::new(STAGE, VERSION, &dh, &params)
}

fn store(m: &VideoMeta, pair: &ScanPair, l: usize, c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(
        k,
        json!({ "L": l, "source": pair.source.name, "target": pair.target.name }),
    )?;
    ne.add_json("video.json", m)?;
    ne.commit()?;
    Ok(())
}

/// What the depth video of a pair reads and its key: the first `l` depth files of each scan
/// (and their content hashes), whether either scan is a LiDAR scan, and the clip.
pub(crate) struct VideoPlan {
    pub(crate) key: CacheKey,
    src_paths: Vec<PathBuf>,
    tgt_paths: Vec<PathBuf>,
    lidar: bool,
    clip: f64,
}

/// The [`VideoPlan`] of the first `l` frames of each scan (hashes the 2L depth files).
pub(crate) fn plan(
    memo: &Memo,
    src_fs: &FrameSet,
    tgt_fs: &FrameSet,
    l: usize,
) -> Result<VideoPlan> {
    let paths = |fs: &FrameSet| -> Vec<PathBuf> {
        fs.frames[..l]
            .iter()
            .map(|f| f.depth_path.clone())
            .collect()
    };
    let (src_paths, tgt_paths) = (paths(src_fs), paths(tgt_fs));
    let depth_hashes: Vec<String> = src_paths
        .par_iter()
        .chain(tgt_paths.par_iter())
        .map(|p| memo.hash_file(p))
        .collect::<Result<_>>()?;
    let (lidar, clip) = pair_clip(src_fs, tgt_fs);
    let key = key(&depth_hashes, l, lidar, clip)?;
    Ok(VideoPlan {
        key,
        src_paths,
        tgt_paths,
        lidar,
        clip,
    })
}

impl VideoPlan {
    /// Whether either scan is a LiDAR (f-theta) scan.
    pub(crate) fn lidar(&self) -> bool {
        self.lidar
    }
}

/// The video's content hash (the generation's input) when `cache` holds the stage's entry.
pub(crate) fn cached_hash(cache: &Cache, key: &CacheKey) -> Option<String> {
    let e = cache.get(key).ok().flatten()?;
    e.read_json::<VideoMeta>("video.json").ok().map(|m| m.hash)
}

/// The depth video of the first `l` frames of each scan, timed as "depth video".
pub(crate) fn run(
    ctx: &mut Ctx,
    pair: &ScanPair,
    src_fs: &FrameSet,
    tgt_fs: &FrameSet,
    l: usize,
) -> Result<DepthVideo> {
    let t = Instant::now();
    let VideoPlan {
        key,
        src_paths,
        tgt_paths,
        lidar,
        clip,
    } = plan(ctx.memo, src_fs, tgt_fs, l)?;
    let mut frames: Option<Vec<RgbImage>> = None;
    let (meta, hit) = ctx.cached(
        &key,
        |e| e.read_json::<VideoMeta>("video.json"),
        || {
            let f = build(&src_paths, &tgt_paths, clip)?;
            let m = meta_of(&f);
            frames = Some(f);
            Ok(m)
        },
        |m, c, k| store(m, pair, l, c, k),
    )?;
    ctx.timer.record_as(NAME, "depth video", t.elapsed(), hit);
    Ok(DepthVideo {
        key: key.hash,
        meta,
        frames,
        src_paths,
        tgt_paths,
        clip,
        lidar,
    })
}
