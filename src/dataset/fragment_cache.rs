//! A content-addressed cache of fragments built from raw RGB-D frames. Building a fragment
//! decodes and back-projects 50 depth PNGs (seconds); the cache key hashes the bytes of every
//! input file (depth, pose, colour when used, intrinsics) and the build options, so an edited
//! frame or option can never return a stale cloud. One `.npy` per fragment (N x 3 points, or
//! N x 6 with colours 0-255), written atomically; a file that does not decode is reported and
//! rebuilt, never used.

use super::fragment::{build_fragment_with, fragment_frames, FragmentOptions};
use super::Scan;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use crate::io::rgbd_sequence::RgbdSequence;
use crate::pipeline::cache::{decode_npy_f32, encode_npy_f32};
use nalgebra::Point3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Bumped whenever the fragment builder's output changes for the same inputs.
const VERSION: &str = "cgenreg-fragment-v1";

/// How a cached build went.
#[derive(Clone, Debug, PartialEq)]
pub enum FragmentCacheStatus {
    Hit,
    Built,
    /// The entry was unreadable (the message says why) and was rebuilt.
    Rebuilt(String),
}

/// How the fragment cache served a pair's scans: whether all of them were hits (None: no
/// fragment came through the cache), and why any entry had to be rebuilt.
pub fn pair_summary(st: &[Option<FragmentCacheStatus>]) -> (Option<bool>, Vec<&str>) {
    let used: Vec<&FragmentCacheStatus> = st.iter().flatten().collect();
    let all_hit = (!used.is_empty()).then(|| used.iter().all(|s| **s == FragmentCacheStatus::Hit));
    let rebuilt = used
        .iter()
        .filter_map(|s| match s {
            FragmentCacheStatus::Rebuilt(why) => Some(why.as_str()),
            _ => None,
        })
        .collect();
    (all_hit, rebuilt)
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// blake3 of everything the fragment depends on.
pub fn fragment_key(
    seq: &RgbdSequence,
    first: usize,
    count: usize,
    opts: &FragmentOptions,
) -> Result<String> {
    let mut files: Vec<PathBuf> = vec![seq.intrinsics_path.clone()];
    for idx in first..first + count {
        let f = super::fragment::fragment_frame(seq, idx, first, count)?;
        files.push(f.depth.clone());
        if let Some(p) = &f.pose {
            files.push(p.clone());
        }
        if opts.with_color {
            if let Some(c) = &f.color {
                files.push(c.clone());
            }
        }
    }
    let digests = files
        .par_iter()
        .map(|p| read(p).map(|b| *blake3::hash(&b).as_bytes()))
        .collect::<Result<Vec<_>>>()?;
    let mut h = blake3::Hasher::new();
    h.update(VERSION.as_bytes());
    h.update(&(first as u64).to_le_bytes());
    h.update(&(count as u64).to_le_bytes());
    for v in [opts.voxel, opts.min_depth, opts.max_depth] {
        h.update(&v.to_le_bytes());
    }
    match &opts.crop {
        Some(c) => {
            for v in c.min.iter().chain(c.max.iter()) {
                h.update(&v.to_le_bytes());
            }
        }
        None => {
            h.update(b"nocrop");
        }
    }
    h.update(&[opts.with_color as u8]);
    for d in &digests {
        h.update(d);
    }
    Ok(h.finalize().to_hex().to_string())
}

fn encode(cloud: &PointCloud) -> Result<Vec<u8>> {
    let cols = if cloud.colors.is_some() { 6 } else { 3 };
    let mut data = Vec::with_capacity(cloud.points.len() * cols);
    for (i, p) in cloud.points.iter().enumerate() {
        data.extend_from_slice(&[p.x, p.y, p.z]);
        if let Some(c) = cloud.colors.as_ref().and_then(|c| c.get(i)) {
            data.extend(c.iter().map(|&v| v as f32));
        }
    }
    encode_npy_f32(cloud.points.len(), cols, &data)
}

fn decode(path: &Path, with_color: bool) -> Result<PointCloud> {
    let bytes = read(path)?;
    let (rows, cols, data) = decode_npy_f32(&bytes, path)?;
    let want = if with_color { 6 } else { 3 };
    if cols != want || rows == 0 {
        return Err(Error::format(
            path,
            "shape",
            format!("(N > 0, {want})"),
            format!("({rows}, {cols})"),
        ));
    }
    let mut points = Vec::with_capacity(rows);
    let mut colors = with_color.then(|| Vec::with_capacity(rows));
    for r in data.chunks_exact(cols) {
        if !r[..3].iter().all(|v| v.is_finite()) {
            return Err(Error::format(
                path,
                "points",
                "finite coordinates",
                "NaN or inf",
            ));
        }
        points.push(Point3::new(r[0], r[1], r[2]));
        if let Some(c) = colors.as_mut() {
            c.push([r[3] as u8, r[4] as u8, r[5] as u8]);
        }
    }
    Ok(PointCloud {
        points,
        colors,
        ..Default::default()
    })
}

/// [`build_fragment_with`] through the cache in `dir` (created when missing).
pub fn build_fragment_cached(
    seq: &RgbdSequence,
    first: usize,
    count: usize,
    opts: &FragmentOptions,
    name: impl Into<String>,
    dir: &Path,
) -> Result<(Scan, FragmentCacheStatus)> {
    let key = fragment_key(seq, first, count, opts)?;
    let path = dir.join(format!("{key}.npy"));
    let mut status = FragmentCacheStatus::Built;
    if path.is_file() {
        match decode(&path, opts.with_color) {
            Ok(cloud) => {
                let frames = fragment_frames(seq, first, count)?;
                return Ok((
                    Scan {
                        name: name.into(),
                        cloud,
                        frames: Some(frames),
                    },
                    FragmentCacheStatus::Hit,
                ));
            }
            Err(e) => status = FragmentCacheStatus::Rebuilt(format!("corrupt cache entry: {e}")),
        }
    }
    let scan = build_fragment_with(seq, first, count, opts, name)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::error::write_atomic(&path, &encode(&scan.cloud)?)?;
    Ok((scan, status))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn demo_seq() -> RgbdSequence {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/source");
        RgbdSequence::open(&dir).unwrap()
    }

    #[test]
    fn hit_equals_build_and_corrupt_entry_is_rebuilt() {
        let seq = demo_seq();
        let n = seq.frames.len().min(4);
        let first = seq.frames[0].index;
        let opts = FragmentOptions::default();
        let tmp = tempfile::tempdir().unwrap();
        let (a, s1) = build_fragment_cached(&seq, first, n, &opts, "a", tmp.path()).unwrap();
        assert_eq!(s1, FragmentCacheStatus::Built);
        let (b, s2) = build_fragment_cached(&seq, first, n, &opts, "a", tmp.path()).unwrap();
        assert_eq!(s2, FragmentCacheStatus::Hit);
        assert_eq!(a.cloud.points, b.cloud.points);
        assert_eq!(
            a.frames.as_ref().map(|f| f.frames.len()),
            b.frames.as_ref().map(|f| f.frames.len())
        );
        // Other options are another entry.
        let opts2 = FragmentOptions {
            voxel: 0.02,
            ..Default::default()
        };
        let (c, s3) = build_fragment_cached(&seq, first, n, &opts2, "a", tmp.path()).unwrap();
        assert_eq!(s3, FragmentCacheStatus::Built);
        assert!(c.cloud.points.len() < a.cloud.points.len());
        // Truncate the first entry: it is reported and rebuilt, never used.
        let key = fragment_key(&seq, first, n, &opts).unwrap();
        let p = tmp.path().join(format!("{key}.npy"));
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let (d, s4) = build_fragment_cached(&seq, first, n, &opts, "a", tmp.path()).unwrap();
        assert!(matches!(s4, FragmentCacheStatus::Rebuilt(_)), "{s4:?}");
        assert_eq!(d.cloud.points, a.cloud.points);
    }

    #[test]
    fn key_changes_with_frame_content() {
        let src = demo_seq();
        let tmp = tempfile::tempdir().unwrap();
        for e in std::fs::read_dir(&src.dir).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), tmp.path().join(e.file_name())).unwrap();
        }
        let seq = RgbdSequence::open(tmp.path()).unwrap();
        let first = seq.frames[0].index;
        let opts = FragmentOptions::default();
        let k1 = fragment_key(&seq, first, 2, &opts).unwrap();
        let pose = seq.frames[1].pose.clone().unwrap();
        let text = std::fs::read_to_string(&pose).unwrap();
        std::fs::write(&pose, format!("{text}\n")).unwrap();
        let k2 = fragment_key(&seq, first, 2, &opts).unwrap();
        assert_ne!(k1, k2);
        // A frame outside the range does not matter.
        let k3 = fragment_key(&seq, first, 1, &opts).unwrap();
        let last = seq.frames.last().unwrap().pose.clone().unwrap();
        std::fs::write(&last, "garbage").unwrap();
        assert_eq!(k3, fragment_key(&seq, first, 1, &opts).unwrap());
    }
}
