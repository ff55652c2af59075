//! Fragments from raw RGB-D sequences, the way the 3DMatch benchmark made them.
//!
//! Fragment k of a sequence is frames `50k .. 50k+49` ([`FRAGMENT_LEN`] = 50). Every valid
//! depth pixel (not 0, not 65535, within `[min_depth, max_depth]`) is back-projected with the
//! pinhole intrinsics (x = (u - cx) z / fx, y = (v - cy) z / fy), mapped into the camera frame
//! of the fragment's first frame by `first_from_camera = inv(P_first) * P_f` (poses are
//! camera-to-world), optionally cropped to a box in that frame, and merged by voxel
//! downsampling. 3DMatch fused a TSDF instead, cropped to x, y in [-1.5, 1.5] m and
//! z in [0.5, 3.5] m of the first frame; [`FragmentOptions::threedmatch`] reproduces that crop.

use super::{FrameSet, RgbdFrame, Scan};
use crate::dataset::rgbd_sequence::RgbdSequence;
use crate::error::{Error, Result};
use crate::geometry::{floor_i64, PointCloud};
use crate::io::depth_png::read_depth_png;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

/// Back-projected points of one frame and their colours (empty without colour).
type FramePoints = (Vec<Point3<f32>>, Vec<[u8; 3]>);

/// Frames per fragment in 3DMatch.
pub const FRAGMENT_LEN: usize = 50;

/// An axis-aligned box in the fragment's (first frame's camera) coordinates, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CropBox {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl CropBox {
    /// The 3DMatch TSDF volume: x, y in [-1.5, 1.5], z in [0.5, 3.5] of the first frame.
    pub const THREEDMATCH: CropBox = CropBox {
        min: [-1.5, -1.5, 0.5],
        max: [1.5, 1.5, 3.5],
    };

    pub fn contains(&self, p: &Point3<f32>) -> bool {
        (0..3).all(|k| (p[k] as f64) >= self.min[k] && (p[k] as f64) <= self.max[k])
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct FragmentOptions {
    /// Voxel size of the merge, metres (<= 0 keeps every back-projected point).
    pub voxel: f64,
    /// Depths (metres, along z) outside [min_depth, max_depth] are dropped.
    pub min_depth: f64,
    pub max_depth: f64,
    /// Keep only points inside this box (first-frame coordinates).
    pub crop: Option<CropBox>,
    /// Attach colours sampled from the colour image at the same pixel. Only meaningful when
    /// colour and depth are registered (true for the synthetic demo, not for 7-Scenes).
    pub with_color: bool,
}

impl Default for FragmentOptions {
    fn default() -> Self {
        FragmentOptions {
            voxel: 0.01,
            min_depth: 0.0,
            max_depth: 4.0,
            crop: None,
            with_color: false,
        }
    }
}

impl FragmentOptions {
    /// Closest to the 3DMatch fragments: 3DMatch's crop box and depth range.
    pub fn threedmatch(voxel: f64) -> Self {
        FragmentOptions {
            voxel,
            crop: Some(CropBox::THREEDMATCH),
            ..Default::default()
        }
    }
}

/// Frame `idx` of the fragment `first .. first+count`, or an error naming the missing file.
pub(super) fn fragment_frame(
    seq: &RgbdSequence,
    idx: usize,
    first: usize,
    count: usize,
) -> Result<&crate::dataset::rgbd_sequence::SequenceFrame> {
    seq.frame(idx).ok_or_else(|| {
        Error::Missing(format!(
            "{}: fragment frames {first}..{} need frame-{idx:06}.depth.png, which is missing",
            seq.dir.display(),
            first + count - 1
        ))
    })
}

/// The frames `first .. first+count` of `seq` with their poses in the first frame's
/// coordinates (`scan_from_camera = inv(P_first) * P_f`).
pub fn fragment_frames(seq: &RgbdSequence, first: usize, count: usize) -> Result<FrameSet> {
    if count == 0 {
        return Err(Error::Param(format!(
            "{}: a fragment needs at least one frame (count = 0)",
            seq.dir.display()
        )));
    }
    let intrinsics = seq.intrinsics()?;
    let world_from_first = seq.world_from_camera(first)?;
    let first_from_world = world_from_first.inverse();
    let frames = (first..first + count)
        .into_par_iter()
        .map(|idx| {
            let f = fragment_frame(seq, idx, first, count)?;
            Ok(RgbdFrame {
                index: idx,
                depth_path: f.depth.clone(),
                color_path: f.color.clone(),
                scan_from_camera: first_from_world * seq.world_from_camera(idx)?,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(FrameSet {
        camera: intrinsics.into(),
        frames,
        origin: super::ViewOrigin::Sensor,
    })
}

/// Back-project one frame into the fragment's coordinates.
fn backproject_frame(
    fs: &FrameSet,
    frame: &RgbdFrame,
    opts: &FragmentOptions,
) -> Result<FramePoints> {
    let k = fs.camera.as_pinhole().ok_or_else(|| {
        Error::Invalid(format!(
            "{}: fragments are fused from pinhole RGB-D frames, this frame set has an {} camera",
            frame.depth_path.display(),
            fs.camera.name()
        ))
    })?;
    let depth = read_depth_png(&frame.depth_path)?;
    if depth.width != k.width || depth.height != k.height {
        return Err(Error::format(
            &frame.depth_path,
            "image size",
            format!("{}x{} like the sequence's first frame", k.width, k.height),
            format!("{}x{}", depth.width, depth.height),
        ));
    }
    let color = match (&frame.color_path, opts.with_color) {
        (Some(p), true) => {
            let bytes = crate::io::limits::read_file(p)?;
            let img = image::load_from_memory(&bytes)
                .map_err(|e| Error::format(p, "image", "a readable colour image", e.to_string()))?
                .to_rgb8();
            if img.width() != k.width || img.height() != k.height {
                return Err(Error::format(
                    p,
                    "image size",
                    format!("{}x{} like the depth image", k.width, k.height),
                    format!("{}x{}", img.width(), img.height()),
                ));
            }
            Some(img)
        }
        _ => None,
    };
    let t: Isometry3<f32> = frame.scan_from_camera.cast();
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let (zmin, zmax) = (opts.min_depth as f32, opts.max_depth as f32);
    let mut pts = Vec::with_capacity(depth.data.len());
    let mut cols = Vec::new();
    for v in 0..depth.height {
        for u in 0..depth.width {
            let Some(z) = depth.meters(u, v) else {
                continue;
            };
            if z < zmin || z > zmax {
                continue;
            }
            let pc = Point3::new((u as f32 - cx) * z / fx, (v as f32 - cy) * z / fy, z);
            let p = t * pc;
            if let Some(b) = &opts.crop {
                if !b.contains(&p) {
                    continue;
                }
            }
            pts.push(p);
            if let Some(img) = &color {
                cols.push(img.get_pixel(u, v).0);
            }
        }
    }
    Ok((pts, cols))
}

/// Build a fragment from `count` frames starting at `first`, with default options
/// (depth <= 4 m, no crop, no colour) and the given merge voxel.
pub fn build_fragment(
    seq: &RgbdSequence,
    first: usize,
    count: usize,
    voxel: f64,
    name: impl Into<String>,
) -> Result<Scan> {
    let opts = FragmentOptions {
        voxel,
        ..Default::default()
    };
    build_fragment_with(seq, first, count, &opts, name)
}

/// Build a fragment with explicit options. Frames are back-projected in parallel.
pub fn build_fragment_with(
    seq: &RgbdSequence,
    first: usize,
    count: usize,
    opts: &FragmentOptions,
    name: impl Into<String>,
) -> Result<Scan> {
    // Also rejects NaN bounds.
    if opts.max_depth.partial_cmp(&opts.min_depth) != Some(std::cmp::Ordering::Greater) {
        return Err(Error::Param(format!(
            "fragment depth range [{}, {}] is empty",
            opts.min_depth, opts.max_depth
        )));
    }
    let fs = fragment_frames(seq, first, count)?;
    let parts = fs
        .frames
        .par_iter()
        .map(|f| {
            crate::cancel::check()?;
            backproject_frame(&fs, f, opts)
        })
        .collect::<Result<Vec<_>>>()?;
    let name = name.into();
    if parts.iter().all(|(p, _)| p.is_empty()) {
        return Err(Error::Invalid(format!(
            "{}: fragment {name} (frames {first}..{}) has no valid depth pixel",
            seq.dir.display(),
            first + count - 1
        )));
    }
    // Colours only when every frame had a colour image.
    let with_color = opts.with_color && parts.iter().all(|(p, c)| c.len() == p.len());
    let cloud = if opts.voxel > 0.0 {
        merge_voxel(&parts, opts.voxel, with_color)
    } else {
        PointCloud {
            points: parts.iter().flat_map(|(p, _)| p.iter().copied()).collect(),
            colors: with_color.then(|| parts.iter().flat_map(|(_, c)| c.iter().copied()).collect()),
            ..Default::default()
        }
    };
    Ok(Scan {
        name,
        cloud,
        frames: Some(fs),
        notes: Vec::new(),
    })
}

/// Fast hash for packed voxel keys (the std SipHash dominates the merge otherwise).
#[derive(Default, Clone, Copy)]
struct KeyHasher(u64);

impl std::hash::Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x100000001b3);
        }
    }
    fn write_u64(&mut self, k: u64) {
        // splitmix64 finaliser: good avalanche for packed integer keys.
        let mut z = k.wrapping_add(0x9E3779B97F4A7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        self.0 = z ^ (z >> 31);
    }
}

type KeyMap = std::collections::HashMap<u64, Acc, std::hash::BuildHasherDefault<KeyHasher>>;

#[derive(Clone, Copy)]
struct Acc {
    n: u32,
    p: [f64; 3],
    c: [u32; 3],
    /// Global index (over all parts in order) of the first point in this voxel.
    first: usize,
}

/// Voxel merge of the frames' points, the same result as
/// [`crate::geometry::voxel::voxel_downsample`] on their concatenation (grid anchored half a voxel
/// below the minimum bound, centroid per voxel, output ordered by each voxel's first point), computed
/// per frame in parallel and then reduced.
fn merge_voxel(parts: &[FramePoints], voxel: f64, with_color: bool) -> PointCloud {
    let lo = parts
        .par_iter()
        .flat_map_iter(|(p, _)| p.iter())
        .map(|p| p.cast::<f64>())
        .reduce(
            || Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY),
            |a, b| a.inf(&b),
        )
        // Same anchor as voxel_downsample (and Open3D): half a voxel below the minimum bound.
        - nalgebra::Vector3::repeat(voxel * 0.5);
    let mut offsets = Vec::with_capacity(parts.len());
    let mut acc = 0usize;
    for (p, _) in parts {
        offsets.push(acc);
        acc += p.len();
    }
    // 21 bits per axis: 2^21 voxels of >= 1 mm is 2 km, far beyond any fragment.
    let key = |q: &Point3<f64>| -> u64 {
        let k = |a: f64, l: f64| floor_i64((a - l) / voxel).clamp(0, (1 << 21) - 1) as u64;
        k(q.x, lo.x) | (k(q.y, lo.y) << 21) | (k(q.z, lo.z) << 42)
    };
    let maps: Vec<KeyMap> = parts
        .par_iter()
        .zip(offsets.par_iter())
        .map(|((pts, cols), &off)| {
            // A frame has about one voxel per two to four of its points: room for that many,
            // so the map is not rehashed while it fills.
            let mut m = KeyMap::with_capacity_and_hasher(pts.len() / 2, Default::default());
            // Neighbouring pixels of a row mostly fall in the same voxel: a run of them is added
            // into a copy of the voxel's accumulator, written back when the voxel changes. The
            // accumulator sees the same additions in the same order as with a lookup per
            // point, so the sums are the same to the bit.
            let mut run: Option<(u64, Acc)> = None;
            for (i, p) in pts.iter().enumerate() {
                let q = p.cast::<f64>();
                let k = key(&q);
                let a = match &mut run {
                    Some((rk, a)) if *rk == k => a,
                    _ => {
                        if let Some((rk, a)) = run.take() {
                            m.insert(rk, a);
                        }
                        let a = m.get(&k).copied().unwrap_or(Acc {
                            n: 0,
                            p: [0.0; 3],
                            c: [0; 3],
                            first: off + i,
                        });
                        &mut run.insert((k, a)).1
                    }
                };
                a.n += 1;
                for k in 0..3 {
                    a.p[k] += q[k];
                }
                if with_color {
                    for (acc, &c) in a.c.iter_mut().zip(&cols[i]) {
                        *acc += c as u32;
                    }
                }
            }
            if let Some((rk, a)) = run {
                m.insert(rk, a);
            }
            m
        })
        .collect();
    let merged = maps
        .into_par_iter()
        .reduce(KeyMap::default, |mut a, mut b| {
            if a.len() < b.len() {
                std::mem::swap(&mut a, &mut b);
            }
            for (k, v) in b {
                a.entry(k)
                    .and_modify(|x| {
                        x.n += v.n;
                        for k in 0..3 {
                            x.p[k] += v.p[k];
                            x.c[k] += v.c[k];
                        }
                        x.first = x.first.min(v.first);
                    })
                    .or_insert(v);
            }
            a
        });
    let mut accs: Vec<Acc> = merged.into_values().collect();
    accs.par_sort_unstable_by_key(|a| a.first);
    let points = accs
        .iter()
        .map(|a| {
            let n = a.n as f64;
            Point3::new(
                (a.p[0] / n) as f32,
                (a.p[1] / n) as f32,
                (a.p[2] / n) as f32,
            )
        })
        .collect();
    let colors = with_color.then(|| {
        accs.iter()
            .map(|a| {
                let n = a.n as f64;
                [0, 1, 2].map(|k| (a.c[k] as f64 / n).round().clamp(0.0, 255.0) as u8)
            })
            .collect()
    });
    PointCloud {
        points,
        colors,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::voxel::voxel_downsample;

    #[test]
    fn parallel_merge_equals_voxel_downsample() {
        let mut s = crate::testing::Lcg(99);
        let mut rnd = || s.unit31_f32();
        let parts: Vec<FramePoints> = (0..7)
            .map(|f| {
                let n = 500 + 300 * f;
                let p: Vec<_> = (0..n)
                    .map(|_| Point3::new(rnd() - 0.3, 2.0 * rnd(), rnd() + 1.0))
                    .collect();
                let c: Vec<_> = (0..n)
                    .map(|_| [(rnd() * 255.0) as u8, (rnd() * 255.0) as u8, 7])
                    .collect();
                (p, c)
            })
            .collect();
        let all = PointCloud {
            points: parts.iter().flat_map(|(p, _)| p.clone()).collect(),
            colors: Some(parts.iter().flat_map(|(_, c)| c.clone()).collect()),
            ..Default::default()
        };
        for voxel in [0.05, 0.13] {
            let a = voxel_downsample(&all, voxel);
            let b = merge_voxel(&parts, voxel, true);
            assert_eq!(a.len(), b.len());
            assert!(a.len() > 100 && a.len() < all.len());
            for (p, q) in a.points.iter().zip(&b.points) {
                assert!((p - q).norm() < 1e-5, "{p} vs {q}");
            }
            let (ca, cb) = (a.colors.unwrap(), b.colors.unwrap());
            for (x, y) in ca.iter().zip(&cb) {
                for k in 0..3 {
                    assert!((x[k] as i32 - y[k] as i32).abs() <= 1);
                }
            }
        }
    }
}
