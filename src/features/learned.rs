//! Precomputed learned features (GeoTransformer, FCGF, Predator, ...) loaded from files, so
//! a user can plug their own network's output into the geometric branch.
//!
//! Accepted files:
//! - `.npz` (NumPy zip) or `.pkl` (pickled dict of arrays) holding one cloud: a points array
//!   (N,3) named `points` (or `xyz`, `coords`, `pts`, `keypoints`, `points_f`) and a feature
//!   array (N,D) named `feats` (or `features`, `descriptors`, `desc`, `feats_f`). A file with
//!   only one GeoTransformer side (`ref_points_f`+`ref_feats_f` or `src_*`) is accepted too.
//! - GeoTransformer pair files (reference §5: a dict with `ref_points_f (Nr,3)`,
//!   `ref_feats_f (Nr,256)`, `src_points_f (Ns,3)`, `src_feats_f (Ns,256)`, float32) via
//!   [`load_geotransformer_pkl`]. For 3DMatch, GeoTransformer's *ref* is `frag_id0` (the
//!   gt.log target i) and *src* is `frag_id1` (source j); the C-GenReg code maps ref to its
//!   own "src" side, so callers decide the roles from the dataset, not from the names.
//!
//! Points are in the fragment's own frame (metres). Features are returned as stored (not
//! L2-normalised); matching normalises them.

use super::Features;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use crate::io::npy::{array_to_cloud, read_npz, shape_str, NpyArray};
use crate::io::pickle::read_pickle_arrays;
use std::collections::BTreeMap;
use std::path::Path;

/// One cloud's points with one feature row per point.
#[derive(Clone, Debug, PartialEq)]
pub struct LearnedFeatures {
    pub points: PointCloud,
    pub feats: Features,
    /// Where they came from: file and array names.
    pub source: String,
}

const POINT_NAMES: [&str; 6] = ["points", "xyz", "coords", "pts", "keypoints", "points_f"];
const FEAT_NAMES: [&str; 5] = ["feats", "features", "descriptors", "desc", "feats_f"];

fn read_arrays(path: &Path) -> Result<BTreeMap<String, NpyArray>> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "npz" => read_npz(path),
        "pkl" | "pickle" => read_pickle_arrays(path),
        other => Err(Error::format(
            path,
            "extension",
            "one of .npz, .pkl, .pickle",
            format!("{other:?}"),
        )),
    }
}

/// Build one side from named arrays, checking shapes and counts.
fn side(
    path: &Path,
    arrays: &BTreeMap<String, NpyArray>,
    pts_name: &str,
    feats_name: &str,
) -> Result<LearnedFeatures> {
    let get = |n: &str| {
        arrays.get(n).ok_or_else(|| {
            Error::format(
                path,
                n,
                "an array with this name",
                format!(
                    "only {}",
                    arrays.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            )
        })
    };
    let (p, f) = (get(pts_name)?, get(feats_name)?);
    let points = array_to_cloud(path, pts_name, p)?;
    let Some((rows, dim)) = f.rows_cols().filter(|&(_, d)| d > 0) else {
        return Err(Error::format(
            path,
            format!("{feats_name} shape"),
            "(N, D) with D > 0",
            shape_str(&f.shape),
        ));
    };
    if rows != points.len() {
        return Err(Error::format(
            path,
            format!("{feats_name} rows"),
            format!("{} (one per point of {pts_name})", points.len()),
            format!("{rows}"),
        ));
    }
    let data = f.to_f32();
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(Error::format(
            path,
            format!("{feats_name} row {}", i / dim),
            "finite values",
            format!("{}", data[i]),
        ));
    }
    Ok(LearnedFeatures {
        points,
        feats: Features::new(dim, data),
        source: format!("{} ({pts_name}, {feats_name})", path.display()),
    })
}

/// Load one cloud's points and learned features from an `.npz` or `.pkl` file.
pub fn load_learned_features(path: &Path) -> Result<LearnedFeatures> {
    let arrays = read_arrays(path)?;
    fn first<'n>(arrays: &BTreeMap<String, NpyArray>, names: &[&'n str]) -> Option<&'n str> {
        names.iter().find(|n| arrays.contains_key(**n)).copied()
    }
    if let (Some(p), Some(f)) = (first(&arrays, &POINT_NAMES), first(&arrays, &FEAT_NAMES)) {
        return side(path, &arrays, p, f);
    }
    let has = |prefix: &str| {
        arrays.contains_key(&format!("{prefix}_points_f"))
            && arrays.contains_key(&format!("{prefix}_feats_f"))
    };
    match (has("ref"), has("src")) {
        (true, false) => side(path, &arrays, "ref_points_f", "ref_feats_f"),
        (false, true) => side(path, &arrays, "src_points_f", "src_feats_f"),
        (true, true) => Err(Error::format(
            path,
            "arrays",
            "one cloud's points and feats",
            "both GeoTransformer sides (ref_* and src_*): use load_geotransformer_pkl",
        )),
        (false, false) => Err(Error::format(
            path,
            "arrays",
            format!(
                "points ({}) and features ({})",
                POINT_NAMES.join("/"),
                FEAT_NAMES.join("/")
            ),
            arrays.keys().cloned().collect::<Vec<_>>().join(", "),
        )),
    }
}

/// Load a GeoTransformer feature file (pickle, or `.npz` with the same names) as
/// (ref, src). For 3DMatch, ref = `frag_id0` (target i of gt.log), src = `frag_id1`.
pub fn load_geotransformer_pkl(path: &Path) -> Result<(LearnedFeatures, LearnedFeatures)> {
    let arrays = read_arrays(path)?;
    let r = side(path, &arrays, "ref_points_f", "ref_feats_f")?;
    let s = side(path, &arrays, "src_points_f", "src_feats_f")?;
    if r.feats.dim != s.feats.dim {
        return Err(Error::format(
            path,
            "src_feats_f shape",
            format!("{} columns like ref_feats_f", r.feats.dim),
            format!("{}", s.feats.dim),
        ));
    }
    Ok((r, s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::npy::encode_npy_f32;
    use crate::io::pickle::tests::{hex, GEO_P4};
    use std::io::Write;

    fn npz(path: &Path, entries: &[(&str, &[usize], Vec<f32>)]) {
        let f = std::fs::File::create(path).unwrap();
        let mut w = zip::ZipWriter::new(f);
        for (name, shape, data) in entries {
            w.start_file(
                format!("{name}.npy"),
                zip::write::SimpleFileOptions::default(),
            )
            .unwrap();
            w.write_all(&encode_npy_f32(shape, data)).unwrap();
        }
        w.finish().unwrap();
    }

    #[test]
    fn npz_points_and_feats() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.npz");
        let pts: Vec<f32> = (0..12).map(|i| i as f32 * 0.1).collect();
        let feats: Vec<f32> = (0..32).map(|i| (i % 5) as f32).collect();
        npz(
            &p,
            &[
                ("points", &[4, 3], pts.clone()),
                ("feats", &[4, 8], feats.clone()),
            ],
        );
        let lf = load_learned_features(&p).unwrap();
        assert_eq!(lf.points.len(), 4);
        assert_eq!(lf.points.points[3].z, pts[11]);
        assert_eq!(lf.feats.dim, 8);
        assert_eq!(lf.feats.data, feats);
        assert!(lf.source.contains("f.npz") && lf.source.contains("feats"));

        // Mismatched counts name the file and the array.
        npz(
            &p,
            &[
                ("xyz", &[4, 3], pts.clone()),
                ("descriptors", &[3, 8], feats[..24].to_vec()),
            ],
        );
        let e = load_learned_features(&p).unwrap_err().to_string();
        assert!(e.contains("f.npz") && e.contains("descriptors rows"), "{e}");
        // Missing feature array.
        npz(&p, &[("points", &[4, 3], pts)]);
        let e = load_learned_features(&p).unwrap_err().to_string();
        assert!(e.contains("features"), "{e}");
    }

    #[test]
    fn geotransformer_pickle_pair_and_single_side() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("0__7-scenes-redkitchen@0@1.pkl");
        std::fs::write(&p, hex(GEO_P4)).unwrap();
        let (r, s) = load_geotransformer_pkl(&p).unwrap();
        assert_eq!((r.points.len(), r.feats.dim), (2, 4));
        assert_eq!((s.points.len(), s.feats.dim), (1, 4));
        assert_eq!(r.feats.row(1), &[0.0, -2.0, 0.0, 0.0]);
        assert_eq!(s.points.points[0].y, 0.5);
        let e = load_learned_features(&p).unwrap_err().to_string();
        assert!(e.contains("load_geotransformer_pkl"), "{e}");

        let one = dir.path().join("one.npz");
        npz(
            &one,
            &[
                ("src_points_f", &[1, 3], vec![1.0, 2.0, 3.0]),
                ("src_feats_f", &[1, 2], vec![0.5, 0.5]),
            ],
        );
        let lf = load_learned_features(&one).unwrap();
        assert_eq!(lf.feats.data, vec![0.5, 0.5]);
        assert!(load_geotransformer_pkl(&one).is_err());
    }
}
