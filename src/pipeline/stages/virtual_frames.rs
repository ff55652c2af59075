//! Stage `virtual-frames`: depth frames for a scan that has only its cloud, rendered from a
//! virtual camera, stored as a cache entry (verified like every other: a flipped bit or a
//! truncated PNG is detected, reported and rebuilt, never used). Two kinds of entry:
//! - pinhole: `l` views along a virtual arc around the cloud
//!   ([`crate::camera::trajectory::virtual_trajectory`], OpenCV axes with y down), z-buffered
//!   splats as 16-bit millimetre PNGs, and `poses.json`. Key: the cloud's content hash;
//!   parameters: L and the trajectory options;
//! - f-theta (LiDAR, appendix B.3): one range image per camera at the sensor origin. Key: the
//!   cloud's content hash; parameters: the camera model, its pose, the ring-gap fill.
//!
//! Without a cache (or when the cache cannot be written: a warning says so) the entries go
//! to a scratch cache that lives as long as the registration.
//!
//! `poses.json` holds each `scan_from_camera` as a 4x4 for people and as the exact bits of
//! its translation and quaternion, read back bit for bit: the `lift` stage keys on the poses,
//! and a pose that went through decimal text would give a second run other keys.

use super::{cloud_hash, load_or_discard};
use crate::cache::{Cache, CacheKey, Entry};
use crate::camera::ftheta::{
    lidar_camera_from_scan_at, lidar_front_camera_from_scan, FThetaCamera,
};
use crate::camera::CameraModel;
use crate::dataset::{FrameSet, RgbdFrame, Scan};
use crate::error::{Error, Result};
use crate::io::limits::ScratchDir;
use crate::pipeline::params::{ImageBranchParams, LidarOrigin, VirtualCamera};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::path::Path;

pub const STAGE: &str = NAME.key_name();
/// 2: a cache entry with a manifest (1 was a bare folder).
pub const VERSION: u32 = 2;
pub const NAME: crate::pipeline::graph::StageName =
    crate::pipeline::graph::StageName::VirtualFrames;

/// What the stage reads of the settings for `scan`: L, the camera (resolved for this scan),
/// the number of f-theta cameras and where their rig stands.
pub fn settings(ib: &ImageBranchParams, scan: &Scan) -> (usize, VirtualCamera, usize, LidarOrigin) {
    let ImageBranchParams {
        backend: _,
        prompt: _,
        seed: _,
        vfm: _,
        k: _,
        margin: _,
        frames_per_fragment,
        lift_radius: _,
        virtual_camera,
        lidar_cameras,
        lidar_origin,
        dense_stride: _,
    } = ib;
    (
        *frames_per_fragment,
        virtual_camera.resolve(&scan.cloud),
        *lidar_cameras,
        *lidar_origin,
    )
}

/// Said with every result whose depth frames were rendered, not sensed.
pub const VIRTUAL_FRAMES_NOTE: &str = "depth frames rendered from a virtual pinhole trajectory \
(the scan had no sensor frames): 640x480, fx = fy = 585, 30° sweep, half the fit-to-view distance";

/// Largest ring gap (pixels, vertical) closed in f-theta range images.
const FTHETA_RING_GAP_PX: u32 = 24;

/// Said with every result whose depth frames come from the virtual f-theta camera.
pub const VIRTUAL_FTHETA_NOTE: &str = "depth frames rendered from a virtual f-theta camera \
(LiDAR, appendix B.3): 1280x640, equidistant, 180° horizontal field of view, looking along \
the scan frame's +x; range in the depth frames, \
no 4 m clip; gaps of up to 24 px between LiDAR rings on one surface filled by interpolation";

/// Frames rendered and encoded at once: bounds the memory of a long trajectory.
const CHUNK: usize = 16;

/// Where virtual frames go: the run's cache, else (no cache, or it cannot be written) a
/// scratch cache removed when this is dropped.
pub struct FrameStore<'a> {
    cache: Option<&'a Cache>,
    scratch: Option<(Cache, ScratchDir)>,
    /// Corrupt entries rebuilt, stores that failed.
    pub warnings: Vec<String>,
    /// The key hashes of the entries read or written, in order (the plan's step).
    pub keys: Vec<String>,
    /// Entries rendered (not read from the cache): the stage's timing row says "computed".
    pub rendered: usize,
}

impl<'a> FrameStore<'a> {
    pub fn new(cache: Option<&'a Cache>) -> Self {
        FrameStore {
            cache,
            scratch: None,
            warnings: Vec::new(),
            keys: Vec::new(),
            rendered: 0,
        }
    }

    fn scratch(&mut self) -> Result<&Cache> {
        if self.scratch.is_none() {
            let dir = ScratchDir::new("cgenreg-virtual-frames")?;
            let c = Cache::open(dir.path())?;
            self.scratch = Some((c, dir));
        }
        match &self.scratch {
            Some((c, _)) => Ok(c),
            None => Err(Error::Missing("no scratch folder".into())),
        }
    }

    /// The verified entry for `key` in the run's cache when it passes `check` (a corrupt one
    /// is left for [`Self::entry`] to report and replace).
    fn hit(&mut self, key: &CacheKey, check: impl Fn(&Entry) -> Result<()>) -> Option<Entry> {
        let e = self.cache?.get(key).ok()??;
        let e = check(&e).ok().map(|_| e)?;
        self.keys.push(key.hash.clone());
        Some(e)
    }

    /// The verified entry for `key` (checked by `check`), else a new one: `n` files named
    /// `name(i)` with the bytes `render(i)`, then `extra` JSON files.
    fn entry(
        &mut self,
        key: &CacheKey,
        provenance: Value,
        files: &Files,
        check: impl Fn(&Entry) -> Result<()>,
    ) -> Result<Entry> {
        self.keys.push(key.hash.clone());
        if let Some(c) = self.cache {
            let verified = |e: &Entry| check(e).map(|()| e.clone());
            if let Some(e) = load_or_discard(c, key, verified, &mut self.warnings, "rebuilt") {
                return Ok(e);
            }
            self.rendered += 1;
            match put(c, key, provenance.clone(), files) {
                Ok(e) => return Ok(e),
                Err(err) => self.warnings.push(format!(
                    "could not write cache entry {}: {err}; its frames are kept in a scratch \
                     folder for this run only",
                    key.short()
                )),
            }
        } else {
            self.rendered += 1;
        }
        let c = self.scratch()?;
        put(c, key, provenance, files)
    }
}

/// What a new entry holds: `n` rendered files and some JSON files.
struct Files<'f> {
    n: usize,
    name: &'f (dyn Fn(usize) -> String + Sync),
    render: &'f (dyn Fn(usize) -> Result<Vec<u8>> + Sync),
    json: Vec<(&'static str, Value)>,
}

fn put(c: &Cache, key: &CacheKey, provenance: Value, f: &Files) -> Result<Entry> {
    let mut ne = c.put(key, provenance)?;
    let idx: Vec<usize> = (0..f.n).collect();
    for chunk in idx.chunks(CHUNK) {
        let bytes: Vec<Vec<u8>> = chunk
            .par_iter()
            .map(|&i| (f.render)(i))
            .collect::<Result<_>>()?;
        for (&i, b) in chunk.iter().zip(&bytes) {
            ne.add_bytes(&(f.name)(i), b)?;
        }
    }
    for (name, v) in &f.json {
        ne.add_json(name, v)?;
    }
    ne.commit()
}

/// One pose as `poses.json` holds it.
#[derive(Serialize, Deserialize)]
struct PoseRecord {
    /// Row-major 4x4, for people and other tools.
    scan_from_camera: [[f64; 4]; 4],
    /// Translation x, y, z and quaternion i, j, k, w as the hex of their f64 bits: exact.
    bits: String,
}

fn pose_record(p: &Isometry3<f64>) -> PoseRecord {
    let q = p.rotation.quaternion();
    let v = [
        p.translation.x,
        p.translation.y,
        p.translation.z,
        q.i,
        q.j,
        q.k,
        q.w,
    ];
    PoseRecord {
        scan_from_camera: crate::pipeline::result::matrix_rows(p),
        bits: v.iter().map(|x| format!("{:016x}", x.to_bits())).collect(),
    }
}

fn pose_from(r: &PoseRecord, file: &Path) -> Result<Isometry3<f64>> {
    let bad = || Error::format(file, "bits", "7 f64 as 112 hex digits", r.bits.clone());
    if r.bits.len() != 7 * 16 || !r.bits.is_ascii() {
        return Err(bad());
    }
    let v: Vec<f64> = (0..7)
        .map(|i| u64::from_str_radix(&r.bits[i * 16..(i + 1) * 16], 16).map(f64::from_bits))
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad())?;
    if v.iter().any(|x| !x.is_finite()) {
        return Err(bad());
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    if (q.norm() - 1.0).abs() > 1e-9 {
        return Err(Error::format(
            file,
            "bits",
            "a unit quaternion",
            format!("norm {}", q.norm()),
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::new_unchecked(q),
    ))
}

fn frame_name(i: usize) -> String {
    format!("frame-{i:06}.depth.png")
}

/// Depth frames of a point-cloud-only scan from the chosen virtual camera: the pinhole
/// trajectory of [`pinhole_frames`], or for LiDAR f-theta cameras at the sensor origin: one
/// facing forward by default (the paper's Waymo setup: "a single forward-facing virtual
/// camera"), or `cameras` evenly spaced in yaw to cover a 360° scan (appendix B.3). A camera
/// does not move, so its one range image stands for its run of the `l` frames (frame i shows
/// camera floor(i * cameras / l)).
pub fn virtual_frames(
    store: &mut FrameStore,
    scan: &Scan,
    l: usize,
    camera: VirtualCamera,
    cameras: usize,
    origin: LidarOrigin,
) -> Result<FrameSet> {
    if camera.resolve(&scan.cloud) != VirtualCamera::Ftheta {
        return pinhole_frames(store, scan, l);
    }
    if l == 0 || cameras == 0 || cameras > l {
        return Err(Error::Param(format!(
            "virtual f-theta frames: {cameras} cameras for L = {l} frames; need 1 <= cameras <= L"
        )));
    }
    let cam = FThetaCamera::default();
    let mut paths = Vec::with_capacity(cameras);
    let mut poses = Vec::with_capacity(cameras);
    // The splat size of every camera's image, estimated once, on the first cache miss.
    let splat = SplatOnce::default();
    for camera_from_scan in ftheta_poses(scan, cameras, origin)? {
        // With one camera an empty image means the scan is not in its sensor frame; with
        // several, a camera facing away from a partial scan may see nothing.
        let e = ftheta_range_image(store, scan, &cam, &camera_from_scan, cameras == 1, &splat)?;
        paths.push(e.path(RANGE_IMAGE));
        poses.push(camera_from_scan.inverse());
    }
    Ok(FrameSet {
        origin: crate::dataset::ViewOrigin::SensorPosition,
        camera: CameraModel::FTheta(cam),
        frames: (0..l)
            .map(|i| {
                let c = i * cameras / l;
                RgbdFrame {
                    index: i,
                    depth_path: paths[c].clone(),
                    color_path: None,
                    scan_from_camera: poses[c],
                }
            })
            .collect(),
    })
}

const RANGE_IMAGE: &str = "range.depth.png";

/// The splat options of one scan's renders, with its point spacing estimated once: the
/// estimate (a k-d tree over the whole cloud) would otherwise be repeated for every view,
/// and it is a function of the points alone, so every view gets the same value as before.
#[derive(Default)]
struct SplatOnce(std::sync::OnceLock<crate::camera::render::SplatOptions>);

impl SplatOnce {
    fn get(&self, points: &[nalgebra::Point3<f32>]) -> &crate::camera::render::SplatOptions {
        self.0.get_or_init(|| crate::camera::render::SplatOptions {
            point_spacing: crate::camera::render::estimate_point_spacing(points),
            ..Default::default()
        })
    }
}

/// `camera_from_scan` of each of the `cameras` f-theta cameras of `scan`, evenly spaced in yaw
/// from the scan frame's +x, standing at the scan frame's origin (bit for bit the poses used
/// before [`LidarOrigin`] existed, so their cache entries keep their keys) or at the sensor
/// position estimated from the scan ([`crate::camera::sensor_origin`]).
pub fn ftheta_poses(
    scan: &Scan,
    cameras: usize,
    origin: LidarOrigin,
) -> Result<Vec<Isometry3<f64>>> {
    let at = match origin {
        LidarOrigin::ScanOrigin => None,
        LidarOrigin::Estimated => Some(
            crate::camera::sensor_origin::estimate_sensor_origin(&scan.cloud.points)
                .map_err(|e| Error::Invalid(format!("{}: {e}", scan.name)))?
                .origin,
        ),
    };
    Ok((0..cameras)
        .map(|c| {
            let yaw = std::f64::consts::TAU * c as f64 / cameras as f64;
            match &at {
                None => lidar_front_camera_from_scan(yaw),
                Some(o) => lidar_camera_from_scan_at(yaw, o),
            }
        })
        .collect())
}

/// The key of one f-theta range image: the cloud, the camera model, the ring-gap fill and the
/// pose.
fn ftheta_key(
    scan: &Scan,
    cam: &FThetaCamera,
    camera_from_scan: &Isometry3<f64>,
) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[&cloud_hash(&scan.cloud)],
        &json!({
            "camera": "ftheta", "model": format!("{cam:?}"), "gap_px": FTHETA_RING_GAP_PX,
            "camera_from_scan": camera_from_scan.to_homogeneous().as_slice(),
        }),
    )
}

/// The pinhole frames' key: the cloud, L and the trajectory options.
fn pinhole_key(
    scan: &Scan,
    l: usize,
    opts: &crate::camera::trajectory::TrajectoryOptions,
) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[&cloud_hash(&scan.cloud)],
        &json!({ "camera": "pinhole", "L": l, "trajectory": format!("{opts:?}") }),
    )
}

/// The trajectory of the virtual pinhole camera. Half the automatic distance: the scan
/// over-fills the view, but its depths stay mostly inside the depth video's 4 m clip
/// (reference §1.2) instead of all beyond it.
fn pinhole_options() -> crate::camera::trajectory::TrajectoryOptions {
    crate::camera::trajectory::TrajectoryOptions {
        distance_scale: 0.5,
        ..Default::default()
    }
}

/// The keys of the entries [`virtual_frames`] reads or writes for `scan` (one for pinhole
/// frames, one per camera for f-theta frames), without rendering anything.
pub fn keys(
    scan: &Scan,
    l: usize,
    camera: VirtualCamera,
    cameras: usize,
    origin: LidarOrigin,
) -> Result<Vec<CacheKey>> {
    if camera.resolve(&scan.cloud) != VirtualCamera::Ftheta {
        return Ok(vec![pinhole_key(scan, l, &pinhole_options())?]);
    }
    let cam = FThetaCamera::default();
    ftheta_poses(scan, cameras, origin)?
        .iter()
        .map(|p| ftheta_key(scan, &cam, p))
        .collect()
}

/// One f-theta range image of `scan` seen with pose `camera_from_scan`.
fn ftheta_range_image(
    store: &mut FrameStore,
    scan: &Scan,
    cam: &FThetaCamera,
    camera_from_scan: &Isometry3<f64>,
    empty_is_error: bool,
    splat: &SplatOnce,
) -> Result<Entry> {
    let key = ftheta_key(scan, cam, camera_from_scan)?;
    let render = || -> Result<Vec<u8>> {
        let points = &scan.cloud.points;
        let mut d = cam.render_depth(points, camera_from_scan, splat.get(points));
        // Rings of a spinning LiDAR are a few degrees apart: about 2-20 px at 1280x640.
        crate::camera::ftheta::fill_ring_gaps(&mut d, FTHETA_RING_GAP_PX, 0.1);
        if empty_is_error && d.data.iter().all(|&v| v == 0) {
            return Err(Error::Invalid(format!(
                "{}: no point is in view of the virtual f-theta camera (at ({:.2}, {:.2}, {:.2}) \
                 in the scan frame, looking along +x); is this a LiDAR scan in its sensor frame \
                 (else try --lidar-origin estimated)?",
                scan.name,
                camera_from_scan.inverse().translation.x,
                camera_from_scan.inverse().translation.y,
                camera_from_scan.inverse().translation.z
            )));
        }
        crate::io::depth_png::encode_depth_png(Path::new(RANGE_IMAGE), &d)
    };
    let has_image = |e: &Entry| -> Result<()> {
        e.manifest
            .files
            .iter()
            .any(|f| f.name == RANGE_IMAGE)
            .then_some(())
            .ok_or_else(|| Error::Cache(format!("{}: no {RANGE_IMAGE}", e.dir.display())))
    };
    if let Some(e) = store.hit(&key, has_image) {
        return Ok(e);
    }
    // Render before the store: an empty view is an error, not a store failure.
    let bytes = render()?;
    let render_i = |_: usize| Ok(bytes.clone());
    let files = Files {
        n: 1,
        name: &|_| RANGE_IMAGE.to_string(),
        render: &render_i,
        json: Vec::new(),
    };
    store.entry(
        &key,
        json!({ "stage": STAGE, "camera": "f-theta", "scan": scan.name }),
        &files,
        has_image,
    )
}

/// Depth frames of a point-cloud-only scan: `l` views along a virtual pinhole arc around the
/// cloud, z-buffered splats as 16-bit millimetre PNGs.
pub fn pinhole_frames(store: &mut FrameStore, scan: &Scan, l: usize) -> Result<FrameSet> {
    use crate::camera::trajectory::virtual_trajectory;
    let opts = pinhole_options();
    let key = pinhole_key(scan, l, &opts)?;
    if let Some(e) = store.hit(&key, |e| read_poses(e, l).map(|_| ())) {
        return frame_set(&e, l, &opts);
    }
    let poses = virtual_trajectory(&scan.cloud, l, &opts)?;
    let records: Vec<PoseRecord> = poses.iter().map(pose_record).collect();
    let splat = SplatOnce::default();
    let render = |i: usize| -> Result<Vec<u8>> {
        let points = &scan.cloud.points;
        let d = crate::camera::render::render_depth_with(
            points,
            &opts.intrinsics,
            &poses[i].inverse(),
            splat.get(points),
        );
        crate::io::depth_png::encode_depth_png(Path::new(&frame_name(i)), &d)
    };
    let poses_json = serde_json::to_value(&records)
        .map_err(|e| Error::Invalid(format!("virtual poses: {e}")))?;
    let files = Files {
        n: l,
        name: &frame_name,
        render: &render,
        json: vec![("poses.json", poses_json)],
    };
    let e = store.entry(
        &key,
        json!({ "stage": STAGE, "camera": "pinhole", "scan": scan.name, "L": l }),
        &files,
        |e| read_poses(e, l).map(|_| ()),
    )?;
    frame_set(&e, l, &opts)
}

/// The frames of a pinhole entry, with the poses as the entry holds them (bit for bit those
/// computed).
fn frame_set(
    e: &Entry,
    l: usize,
    opts: &crate::camera::trajectory::TrajectoryOptions,
) -> Result<FrameSet> {
    let poses = read_poses(e, l)?;
    Ok(FrameSet {
        origin: crate::dataset::ViewOrigin::Virtual,
        camera: opts.intrinsics.into(),
        frames: poses
            .into_iter()
            .enumerate()
            .map(|(i, scan_from_camera)| RgbdFrame {
                index: i,
                depth_path: e.path(&frame_name(i)),
                color_path: None,
                scan_from_camera,
            })
            .collect(),
    })
}

/// The entry's `l` poses; an error when it does not hold `l` frames and their poses.
fn read_poses(e: &Entry, l: usize) -> Result<Vec<Isometry3<f64>>> {
    let records: Vec<PoseRecord> = e.read_json("poses.json")?;
    let file = e.path("poses.json");
    if records.len() != l
        || (0..l).any(|i| !e.manifest.files.iter().any(|f| f.name == frame_name(i)))
    {
        return Err(Error::Cache(format!(
            "{}: {} poses, frames for L = {l} expected",
            e.dir.display(),
            records.len()
        )));
    }
    records.iter().map(|r| pose_from(r, &file)).collect()
}

/// The pair with virtual depth frames for each scan that has none, and the notes that say
/// so (one per kind of camera).
pub fn with_virtual_frames(
    store: &mut FrameStore,
    pair: &crate::dataset::ScanPair,
    ib: &ImageBranchParams,
) -> Result<(crate::dataset::ScanPair, Vec<String>)> {
    let mut p2 = pair.clone();
    let mut notes = Vec::new();
    for scan in [&mut p2.source, &mut p2.target] {
        if scan.frames.is_some() {
            continue;
        }
        let (l, cam, cameras, origin) = settings(ib, scan);
        scan.frames = Some(virtual_frames(store, scan, l, cam, cameras, origin)?);
        let mut note = match cam {
            VirtualCamera::Ftheta if ib.lidar_cameras > 1 => format!(
                "{VIRTUAL_FTHETA_NOTE}; {} such cameras, {:.0}° apart in yaw, shown one \
                 after the other in the depth video",
                ib.lidar_cameras,
                360.0 / ib.lidar_cameras as f64
            ),
            VirtualCamera::Ftheta => VIRTUAL_FTHETA_NOTE.to_string(),
            _ => VIRTUAL_FRAMES_NOTE.to_string(),
        };
        if cam == VirtualCamera::Ftheta {
            let at = scan
                .frames
                .as_ref()
                .and_then(|f| f.frames.first())
                .map(|f| f.scan_from_camera.translation.vector)
                .unwrap_or_else(nalgebra::Vector3::zeros);
            note.push_str(&match ib.lidar_origin {
                LidarOrigin::ScanOrigin => {
                    "; cameras at the scan frame's origin (the sensor is assumed there)".to_string()
                }
                LidarOrigin::Estimated => format!(
                    "; {}: cameras at the sensor position estimated from the scan's ground \
                     rings, ({:.2}, {:.2}, {:.2}) m in the scan frame (no pose or GT read)",
                    scan.name, at.x, at.y, at.z
                ),
            });
        }
        if !notes.contains(&note) {
            notes.push(note);
        }
    }
    Ok((p2, notes))
}

/// `pair` with depth frames on both scans: borrowed when it has them, else with virtual
/// frames for the scans that lack them (read from or written to `store`), and the notes
/// that say so.
pub fn framed_pair<'a>(
    store: &mut FrameStore,
    pair: &'a crate::dataset::ScanPair,
    ib: &ImageBranchParams,
) -> Result<(std::borrow::Cow<'a, crate::dataset::ScanPair>, Vec<String>)> {
    if pair.source.frames.is_some() && pair.target.frames.is_some() {
        return Ok((std::borrow::Cow::Borrowed(pair), Vec::new()));
    }
    let (p, notes) = with_virtual_frames(store, pair, ib)?;
    Ok((std::borrow::Cow::Owned(p), notes))
}

/// The views follow the reference's stride rule, not the cameras: a warning per side when
/// some of the `ib.lidar_cameras` f-theta cameras were never looked at.
pub fn camera_coverage_warnings(
    img: &crate::pipeline::result::ImageBranchOutput,
    ib: &ImageBranchParams,
) -> Vec<String> {
    let mut out = Vec::new();
    if ib.lidar_cameras <= 1 {
        return out;
    }
    for (side, views) in [("source", &img.source_views), ("target", &img.target_views)] {
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
            out.push(format!(
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
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_round_trip_bit_for_bit() {
        let p = Isometry3::new(
            nalgebra::Vector3::new(0.1, -2.0 / 3.0, 1e-17),
            nalgebra::Vector3::new(0.3, 0.2, -1.1),
        );
        let back = pose_from(&pose_record(&p), Path::new("poses.json")).unwrap();
        assert_eq!(back.translation.vector, p.translation.vector);
        assert_eq!(back.rotation.coords, p.rotation.coords);
        assert_eq!(back.to_homogeneous(), p.to_homogeneous());
        let mut r = pose_record(&p);
        r.bits.truncate(100);
        assert!(pose_from(&r, Path::new("poses.json")).is_err());
    }

    /// The rig's position is part of the `virtual-frames` key: the estimated origin gives other
    /// keys than the scan's origin, whose keys are those of the poses used before the choice
    /// existed; the estimated cameras stand at the synthetic sensor.
    #[test]
    fn the_estimated_rig_position_is_in_the_key() {
        let sensor = nalgebra::Point3::new(-17.5, 9.25, 0.0);
        let points = crate::camera::sensor_origin::synthetic_ring_scan(
            sensor,
            -1.8,
            32,
            1800,
            (Some(2.0), None),
        );
        let n = points.len();
        let mut cloud = crate::geometry::PointCloud::from_points(points);
        cloud.intensity = Some(vec![10.0; n]);
        let scan = Scan {
            name: "ring".into(),
            cloud,
            frames: None,
            notes: Vec::new(),
        };
        let at_origin = keys(&scan, 50, VirtualCamera::Auto, 2, LidarOrigin::ScanOrigin).unwrap();
        let estimated = keys(&scan, 50, VirtualCamera::Auto, 2, LidarOrigin::Estimated).unwrap();
        let cam = FThetaCamera::default();
        let old: Vec<CacheKey> = [0.0, std::f64::consts::PI]
            .iter()
            .map(|&y| ftheta_key(&scan, &cam, &lidar_front_camera_from_scan(y)).unwrap())
            .collect();
        assert_eq!(at_origin, old);
        assert_eq!(estimated.len(), 2);
        assert!(estimated.iter().all(|k| !at_origin.contains(k)));
        for p in ftheta_poses(&scan, 2, LidarOrigin::Estimated).unwrap() {
            let t = p.inverse().translation.vector;
            assert!((t - sensor.coords).norm() < 0.05, "{t:?}");
        }
    }
}
