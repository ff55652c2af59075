//! The cached stages of the registration, one file each. Every stage has a `VERSION`
//! (bumped when its output changes for the same inputs), a key function (the keys or content
//! hashes of its inputs plus the parameters it reads), its compute, and the load / store of
//! its cache entry through [`Cache`]; [`Ctx::stage`] runs one: a verified hit is loaded, a
//! corrupt entry is reported, removed and recomputed, a store that fails only warns.
//!
//! | stage (cache dir)      | file                   | inputs                                  |
//! |------------------------|------------------------|-----------------------------------------|
//! | `fragments`            | `dataset/fragment_cache.rs` | raw RGB-D frames' bytes            |
//! | `virtual-frames`       | `virtual_frames.rs`    | cloud (scans without sensor frames)     |
//! | `geo-fpfh`             | `geo.rs`               | cloud                                   |
//! | `geo-spinnet`          | `geo_spinnet.rs`       | cloud, SpinNet export                   |
//! | `depth-video`          | `depth_video.rs`       | first L depth frames of both scans      |
//! | `generation`           | `generation.rs`        | depth video (a world model); a side's   |
//! |                        |                        | selected depth (colour) frames (a       |
//! |                        |                        | frame-by-frame backend: builtin, oracle)|
//! | (in memory)            | `view_select.rs`       | video length, L, m, K                   |
//! | `vfm-view`             | `vfm.rs`               | generation, frame                       |
//! | `lift`                 | `lift.rs`              | geo keypoints, selected depth frames    |
//! | `image-points`         | `image_points.rs`      | lifts, vfm views                        |
//! | `image-points-pair`    | `pair_vfm.rs`          | lifts, generation (pair models)         |
//!
//! `docs/architecture.md` has the parameters and keys of each. Every stage exports its typed
//! name (`NAME`, a [`StageName`]) and `settings`, the parameters its key reads (every field of
//! the parameter types claimed or waived). `pipeline/plan.rs` orders the stages and gives
//! their keys before a run ([`super::plan::plan`]); which stages a change invalidates is
//! [`invalidated`].

pub mod depth_video;
pub mod generation;
pub mod geo;
pub mod geo_spinnet;
pub mod image_points;
pub mod lift;
pub mod pair_vfm;
pub mod vfm;
pub mod view_select;
pub mod virtual_frames;

pub use super::graph::StageName;

use super::memo::Memo;
use super::result::Timer;
use crate::cache::{Cache, CacheKey, Entry};
use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use nalgebra::Point3;
use std::path::Path;
use std::time::Instant;

/// What the stages of one registration share: the cache (None: all in memory), the caller's
/// in-memory memo (file hashes, loaded models), the timer and the warnings that go into the
/// result.
pub(crate) struct Ctx<'a> {
    pub(crate) cache: Option<&'a Cache>,
    pub(crate) memo: &'a Memo,
    pub(crate) timer: Timer,
    pub(crate) warnings: Vec<String>,
}

impl<'a> Ctx<'a> {
    pub(crate) fn new(cache: Option<&'a Cache>, memo: &'a Memo) -> Self {
        Ctx {
            cache,
            memo,
            timer: Timer::new(),
            warnings: Vec::new(),
        }
    }

    /// The cached value for `key` (verified), or `compute` then `store`. A corrupt entry is
    /// reported in the warnings, removed and recomputed, never used; a failed store warns.
    /// Returns the value and whether it was a hit.
    pub(crate) fn cached<T>(
        &mut self,
        key: &CacheKey,
        load: impl FnOnce(&Entry) -> Result<T>,
        compute: impl FnOnce() -> Result<T>,
        store: impl FnOnce(&T, &Cache, &CacheKey) -> Result<()>,
    ) -> Result<(T, bool)> {
        if let Some(c) = self.cache {
            if let Some(v) = load_or_discard(c, key, load, &mut self.warnings, "recomputed") {
                return Ok((v, true));
            }
        }
        crate::cancel::check()?;
        let v = compute()?;
        crate::cancel::check()?;
        if let Some(c) = self.cache {
            if let Err(e) = store(&v, c, key) {
                self.warnings
                    .push(format!("could not write cache entry {}: {e}", key.short()));
            }
        }
        Ok((v, false))
    }

    /// [`Self::cached`], timed as a step of the stage `name` (shown as `label`).
    pub(crate) fn stage<T>(
        &mut self,
        name: StageName,
        label: &str,
        key: &CacheKey,
        load: impl FnOnce(&Entry) -> Result<T>,
        compute: impl FnOnce() -> Result<T>,
        store: impl FnOnce(&T, &Cache, &CacheKey) -> Result<()>,
    ) -> Result<T> {
        let t = Instant::now();
        let (v, hit) = self.cached(key, load, compute, store)?;
        self.timer.record_as(name, label, t.elapsed(), hit);
        Ok(v)
    }
}

/// The entry for `key` in `c`, verified and read by `load`. A corrupt entry (verification or
/// `load` fails) is never used: it is reported in `warnings` ("not used, `redo`"), removed,
/// and None returned, as for an absent one.
pub(crate) fn load_or_discard<T>(
    c: &Cache,
    key: &CacheKey,
    load: impl FnOnce(&Entry) -> Result<T>,
    warnings: &mut Vec<String>,
    redo: &str,
) -> Option<T> {
    let problem = match c.get(key) {
        Ok(Some(e)) => match load(&e) {
            Ok(v) => return Some(v),
            Err(err) => err.to_string(),
        },
        Ok(None) => return None,
        Err(err) => err.to_string(),
    };
    warnings.push(format!(
        "cache entry {} is corrupt ({problem}); not used, {redo}",
        key.short()
    ));
    let _ = c.remove(key);
    None
}

/// Content hash of a cloud's points (x, y, z little-endian f32).
/// The bytes go to blake3 in blocks of 4096 points (one update per value cost more than the
/// hash itself; the hashed byte stream is the same).
pub(crate) fn cloud_hash(c: &PointCloud) -> String {
    let mut h = blake3::Hasher::new();
    let mut buf = Vec::with_capacity(4096 * 12);
    for block in c.points.chunks(4096) {
        buf.clear();
        for p in block {
            buf.extend_from_slice(&p.x.to_le_bytes());
            buf.extend_from_slice(&p.y.to_le_bytes());
            buf.extend_from_slice(&p.z.to_le_bytes());
        }
        h.update(&buf);
    }
    h.finalize().to_hex().to_string()
}

pub(crate) fn points_flat(p: &[Point3<f32>]) -> Vec<f32> {
    p.iter().flat_map(|q| [q.x, q.y, q.z]).collect()
}

pub(crate) fn points_from(
    rows: usize,
    cols: usize,
    d: &[f32],
    what: &Path,
) -> Result<Vec<Point3<f32>>> {
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

#[cfg(test)]
mod cloud_hash_tests {
    use super::*;

    /// The blocked hash is the hash of the whole x, y, z byte stream (the keys stay the same).
    #[test]
    fn cloud_hash_is_the_hash_of_the_byte_stream() {
        let pts: Vec<nalgebra::Point3<f32>> = (0..10_001)
            .map(|i| nalgebra::Point3::new(i as f32 * 0.5, -(i as f32), 1.0 / (i as f32 + 1.0)))
            .collect();
        let bytes: Vec<u8> = pts
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .flat_map(f32::to_le_bytes)
            .collect();
        let c = PointCloud::from_points(pts);
        assert_eq!(cloud_hash(&c), blake3::hash(&bytes).to_hex().to_string());
        let empty = PointCloud::from_points(Vec::new());
        assert_eq!(cloud_hash(&empty), blake3::hash(&[]).to_hex().to_string());
    }
}
