//! Stage `fragments`: fragments built from raw RGB-D frames, as entries of the stage cache
//! ([`Cache`]: verified on every read, listed by `cgenreg cache list`, removable). Building a
//! fragment decodes and back-projects 50 depth PNGs (seconds); the key hashes the bytes of
//! every input file (depth, pose, colour when used, intrinsics) and the build options, so an
//! edited frame or option can never return a stale cloud. The entry holds `points.npy`
//! (N x 3 points, or N x 6 with colours 0-255); an entry that fails verification or does not
//! decode is reported and rebuilt, never used, and a store that fails (read-only folder, full
//! disk) is reported while the fragment built in memory is used.

use super::fragment::{build_fragment_with, fragment_frames, FragmentOptions};
use super::Scan;
use crate::cache::{Cache, CacheKey, Entry};
use crate::dataset::rgbd_sequence::RgbdSequence;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use nalgebra::Point3;
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};

pub const STAGE: &str = "fragments";
/// Bumped whenever the fragment builder's output changes for the same inputs (2: a stage
/// cache entry; 1 was a bare `fragments/<key>.npy`).
pub const VERSION: u32 = 2;

const POINTS: &str = "points.npy";

/// How a cached build went.
#[derive(Clone, Debug, PartialEq)]
pub enum FragmentCacheStatus {
    Hit,
    Built,
    /// The entry was unreadable (the message says why) and was rebuilt.
    Rebuilt(String),
    /// Built (or rebuilt), but the entry could not be written (the message says why); the
    /// fragment built in memory is used.
    NotStored(String),
}

/// How the fragment cache served a pair's scans: whether all of them were hits (None: no
/// fragment came through the cache), and a warning for each entry that had to be rebuilt or
/// could not be stored.
pub fn pair_summary(st: &[Option<FragmentCacheStatus>]) -> (Option<bool>, Vec<String>) {
    let used: Vec<&FragmentCacheStatus> = st.iter().flatten().collect();
    let all_hit = (!used.is_empty()).then(|| used.iter().all(|s| **s == FragmentCacheStatus::Hit));
    let warnings = used
        .iter()
        .filter_map(|s| match s {
            FragmentCacheStatus::Rebuilt(why) => Some(format!("{why} (rebuilt)")),
            FragmentCacheStatus::NotStored(why) => Some(format!("{why} (used from memory)")),
            _ => None,
        })
        .collect();
    (all_hit, warnings)
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// The stage key: the content hash of every input file, and the build options.
pub fn fragment_key(
    seq: &RgbdSequence,
    first: usize,
    count: usize,
    opts: &FragmentOptions,
) -> Result<CacheKey> {
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
        .map(|p| read(p).map(|b| blake3::hash(&b).to_hex().to_string()))
        .collect::<Result<Vec<_>>>()?;
    let inputs: Vec<&str> = digests.iter().map(String::as_str).collect();
    let crop = opts
        .crop
        .as_ref()
        .map(|c| json!({ "min": c.min, "max": c.max }));
    CacheKey::new(
        STAGE,
        VERSION,
        &inputs,
        &json!({
            "first": first, "count": count, "voxel": opts.voxel, "min_depth": opts.min_depth,
            "max_depth": opts.max_depth, "crop": crop, "with_color": opts.with_color,
        }),
    )
}

fn matrix(cloud: &PointCloud) -> (usize, usize, Vec<f32>) {
    let cols = if cloud.colors.is_some() { 6 } else { 3 };
    let mut data = Vec::with_capacity(cloud.points.len() * cols);
    for (i, p) in cloud.points.iter().enumerate() {
        data.extend_from_slice(&[p.x, p.y, p.z]);
        if let Some(c) = cloud.colors.as_ref().and_then(|c| c.get(i)) {
            data.extend(c.iter().map(|&v| v as f32));
        }
    }
    (cloud.points.len(), cols, data)
}

fn decode(e: &Entry, with_color: bool) -> Result<PointCloud> {
    let path = e.path(POINTS);
    let (rows, cols, data) = e.read_f32_matrix(POINTS)?;
    let want = if with_color { 6 } else { 3 };
    if cols != want || rows == 0 {
        return Err(Error::format(
            &path,
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
                &path,
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

fn store(cache: &Cache, key: &CacheKey, scan: &Scan, seq: &RgbdSequence) -> Result<()> {
    let (rows, cols, data) = matrix(&scan.cloud);
    let mut ne = cache.put(
        key,
        json!({ "stage": STAGE, "scan": scan.name, "sequence": seq.dir.display().to_string() }),
    )?;
    ne.add_f32_matrix(POINTS, rows, cols, &data)?;
    ne.commit()?;
    Ok(())
}

/// [`build_fragment_with`] through the stage cache `cache`.
pub fn build_fragment_cached(
    seq: &RgbdSequence,
    first: usize,
    count: usize,
    opts: &FragmentOptions,
    name: impl Into<String>,
    cache: &Cache,
) -> Result<(Scan, FragmentCacheStatus)> {
    let key = fragment_key(seq, first, count, opts)?;
    let mut rebuilt: Option<String> = None;
    let found = cache
        .get(&key)
        .and_then(|e| e.map(|e| decode(&e, opts.with_color)).transpose());
    match found {
        Ok(Some(cloud)) => {
            let frames = fragment_frames(seq, first, count)?;
            return Ok((
                Scan {
                    name: name.into(),
                    cloud,
                    frames: Some(frames),
                    notes: Vec::new(),
                },
                FragmentCacheStatus::Hit,
            ));
        }
        Ok(None) => {}
        Err(e) => {
            rebuilt = Some(format!("corrupt cache entry {}: {e}", key.short()));
            let _ = cache.remove(&key);
        }
    }
    let scan = build_fragment_with(seq, first, count, opts, name)?;
    let status = match (store(cache, &key, &scan, seq), rebuilt) {
        (Ok(()), None) => FragmentCacheStatus::Built,
        (Ok(()), Some(why)) => FragmentCacheStatus::Rebuilt(why),
        (Err(e), why) => FragmentCacheStatus::NotStored(format!(
            "{}could not write cache entry {}: {e}",
            why.map(|w| format!("{w}; ")).unwrap_or_default(),
            key.short()
        )),
    };
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
        let cache = Cache::open(tmp.path()).unwrap();
        let (a, s1) = build_fragment_cached(&seq, first, n, &opts, "a", &cache).unwrap();
        assert_eq!(s1, FragmentCacheStatus::Built);
        let (b, s2) = build_fragment_cached(&seq, first, n, &opts, "a", &cache).unwrap();
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
        let (c, s3) = build_fragment_cached(&seq, first, n, &opts2, "a", &cache).unwrap();
        assert_eq!(s3, FragmentCacheStatus::Built);
        assert!(c.cloud.points.len() < a.cloud.points.len());
        assert_eq!(cache.list().unwrap().len(), 2);
        assert!(cache.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
        let key = fragment_key(&seq, first, n, &opts).unwrap();
        let p = cache.get(&key).unwrap().unwrap().path(POINTS);
        let bytes = std::fs::read(&p).unwrap();
        // A flipped bit in one coordinate (still a valid .npy), a moved point, a truncation:
        // each is reported and rebuilt, never used.
        let mut flipped = bytes.clone();
        let last = flipped.len() - 2;
        flipped[last] ^= 0x10;
        let mut moved = bytes.clone();
        let at = moved.len() - 12;
        moved[at..at + 4].copy_from_slice(&7.5f32.to_le_bytes());
        for bad in [flipped, moved, bytes[..bytes.len() / 2].to_vec()] {
            std::fs::write(&p, &bad).unwrap();
            let (d, s4) = build_fragment_cached(&seq, first, n, &opts, "a", &cache).unwrap();
            assert!(matches!(s4, FragmentCacheStatus::Rebuilt(_)), "{s4:?}");
            assert_eq!(d.cloud.points, a.cloud.points);
            assert_eq!(std::fs::read(&p).unwrap(), bytes, "the entry is rebuilt");
        }
    }

    /// A cache that cannot be written: the fragment built in memory is used, with a warning.
    #[cfg(unix)]
    #[test]
    fn unwritable_cache_warns_and_goes_on() {
        use std::os::unix::fs::PermissionsExt;
        let seq = demo_seq();
        let first = seq.frames[0].index;
        let opts = FragmentOptions::default();
        let tmp = tempfile::tempdir().unwrap();
        let cache = Cache::open(tmp.path()).unwrap();
        let stage = tmp.path().join(STAGE);
        std::fs::create_dir_all(&stage).unwrap();
        std::fs::set_permissions(&stage, std::fs::Permissions::from_mode(0o555)).unwrap();
        // Root ignores permissions: then there is nothing to test.
        let probe = stage.join(".probe");
        let writable = std::fs::write(&probe, b"x").is_ok();
        let _ = std::fs::remove_file(&probe);
        let r = build_fragment_cached(&seq, first, 2, &opts, "a", &cache);
        std::fs::set_permissions(&stage, std::fs::Permissions::from_mode(0o755)).unwrap();
        let (scan, st) = r.unwrap();
        assert!(!scan.cloud.is_empty());
        if !writable {
            assert!(
                matches!(&st, FragmentCacheStatus::NotStored(w) if w.contains("could not write")),
                "{st:?}"
            );
            let (_, w) = pair_summary(&[Some(st)]);
            assert_eq!(w.len(), 1);
        }
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
