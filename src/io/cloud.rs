//! Load or save a point cloud by file extension (the checks every cloud reader makes are
//! `validate.rs`, below the readers).
//!
//! Extensions (case-insensitive): `.ply`, `.pcd`, `.npy` (an (N,3) float array), `.pth`
//! (legacy PyTorch pickle of an (N,3) NumPy array), `.bin` (KITTI x,y,z,intensity f32, or
//! x,y,z f32 when `CGENREG_KITTI_FIELDS=3` or the size allows nothing else; see [`super::kitti`]),
//! `.xyz` / `.txt` / `.pts` (whitespace text, x y z per line). Coordinates are taken as stored
//! (metres for all staged data); no frame change is applied.

pub use super::validate::validate_cloud;

use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use std::path::Path;

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

const LOAD_EXTS: &str = ".ply, .pcd, .npy, .pth, .bin, .xyz, .txt, .pts";

/// Read a cloud, choosing the reader by extension.
pub fn load_cloud(path: &Path) -> Result<PointCloud> {
    match extension(path).as_str() {
        "ply" => super::ply::read_ply(path),
        "pcd" => super::pcd::read_pcd(path),
        "npy" => super::npy::read_npy_points(path),
        "pth" => super::pickle::read_pth_points(path),
        "bin" => super::kitti::read_kitti_bin(path),
        "xyz" | "txt" | "pts" => super::xyz::read_xyz(path),
        other => Err(Error::format(
            path,
            "extension",
            format!("one of {LOAD_EXTS}"),
            format!("{other:?}"),
        )),
    }
}

/// [`load_cloud`] with what reading found, for the results: points dropped for a NaN or
/// infinite coordinate (PCD clouds with `is_dense` false) and far outliers
/// ([`crate::geometry::voxel::robust_bounds`]), each with the file named.
pub fn load_cloud_noted(path: &Path) -> Result<(PointCloud, Vec<String>)> {
    let (cloud, dropped) = match extension(path).as_str() {
        "pcd" => super::pcd::read_pcd_counted(path)?,
        _ => (load_cloud(path)?, 0),
    };
    let notes = cloud_notes(path, &cloud, dropped);
    Ok((cloud, notes))
}

/// The notes of [`load_cloud_noted`] for a cloud read from `path` with `dropped` non-finite
/// points left out.
pub fn cloud_notes(path: &Path, cloud: &PointCloud, dropped: usize) -> Vec<String> {
    let mut notes = Vec::new();
    if dropped > 0 {
        notes.push(format!(
            "{}: {dropped} of {} points had a NaN or infinite coordinate (no return) and were \
             dropped",
            path.display(),
            dropped + cloud.len()
        ));
    }
    if let Some((lo, hi, far)) = crate::geometry::voxel::robust_bounds(&cloud.points) {
        if far > 0 {
            notes.push(format!(
                "{}: {far} far outlier point(s), more than {}x the cloud's extent outside the \
                 box ({:.3}, {:.3}, {:.3})-({:.3}, {:.3}, {:.3}) that holds the others; they do \
                 not shape the voxel grid",
                path.display(),
                crate::geometry::voxel::FAR_OUTLIER_FACTOR,
                lo.x,
                lo.y,
                lo.z,
                hi.x,
                hi.y,
                hi.z
            ));
        }
    }
    notes
}

/// Write a cloud, choosing the writer by extension: `.ply` (binary, all attributes),
/// `.npy` ((N,3) float32, points only), `.xyz`/`.txt`/`.pts` (text, points only).
pub fn save_cloud(path: &Path, cloud: &PointCloud) -> Result<()> {
    match extension(path).as_str() {
        "ply" => super::ply::write_ply(path, cloud),
        "npy" => {
            let flat: Vec<f32> = cloud.points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
            super::npy::write_npy_f32(path, &[cloud.len(), 3], &flat)
        }
        "xyz" | "txt" | "pts" => super::xyz::write_xyz(path, cloud),
        other => Err(Error::format(
            path,
            "extension",
            "one of .ply, .npy, .xyz, .txt, .pts",
            format!("{other:?}"),
        )),
    }
}

/// [`save_cloud`] through the output guard ([`crate::io::output::write`], kind `Cloud`): the
/// folder must exist, links, FIFOs and devices are refused, the write is atomic, and an
/// existing file is replaced only when it is a PLY cgenreg wrote, or with `force`. What the
/// Python package's `write_cloud` runs.
pub fn save_cloud_guarded(path: &Path, cloud: &PointCloud, force: bool) -> Result<()> {
    use super::output::{prepare, write, OutputKind};
    // before encoding: a bad path fails at once
    prepare(path, OutputKind::Cloud, force)?;
    let bytes = match extension(path).as_str() {
        "ply" => super::ply::encode_ply(cloud),
        "npy" => {
            let flat: Vec<f32> = cloud.points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
            super::npy::encode_npy_f32(&[cloud.len(), 3], &flat)
        }
        "xyz" | "txt" | "pts" => super::xyz::encode_xyz(cloud).into_bytes(),
        other => {
            return Err(Error::format(
                path,
                "extension",
                "one of .ply, .npy, .xyz, .txt, .pts",
                format!("{other:?}"),
            ))
        }
    };
    write(path, OutputKind::Cloud, force, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn unknown_extension_is_an_error() {
        let e = load_cloud(Path::new("/tmp/x.obj")).unwrap_err().to_string();
        assert!(e.contains("x.obj") && e.contains("extension"), "{e}");
        let c = PointCloud::from_points(vec![Point3::new(0.0, 0.0, 0.0)]);
        assert!(save_cloud(Path::new("/tmp/x.pcd"), &c).is_err());
    }

    #[test]
    fn round_trip_through_every_writer() {
        let dir = tempfile::tempdir().unwrap();
        let pts: Vec<Point3<f32>> = (0..50)
            .map(|i| Point3::new(i as f32 * 0.1, -(i as f32) * 0.25, 1.0 + i as f32 * 1e-3))
            .collect();
        let c = PointCloud::from_points(pts.clone());
        for ext in ["ply", "npy", "xyz", "txt", "pts"] {
            let p = dir.path().join(format!("c.{ext}"));
            save_cloud(&p, &c).unwrap();
            let back = load_cloud(&p).unwrap();
            assert_eq!(back.len(), 50, "{ext}");
            for (a, b) in back.points.iter().zip(&pts) {
                assert!((a - b).norm() < 1e-6, "{ext}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn validation_names_the_bad_point() {
        let mut c = PointCloud::from_points(vec![Point3::new(0.0, 0.0, 0.0); 4]);
        c.points[2].y = f32::NAN;
        let e = validate_cloud(Path::new("a.ply"), &c)
            .unwrap_err()
            .to_string();
        assert!(e.contains("a.ply") && e.contains("point 2"), "{e}");
        let e = validate_cloud(Path::new("a.ply"), &PointCloud::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("empty"), "{e}");
        let mut c = PointCloud::from_points(vec![Point3::new(0.0, 0.0, 0.0); 4]);
        c.intensity = Some(vec![0.0; 3]);
        assert!(validate_cloud(Path::new("a.ply"), &c).is_err());
    }

    /// Every staged cloud file, through the dispatcher, with the MANIFEST point counts.
    const STAGED: [(&str, usize); 13] = [
        (
            "3dmatch-redkitchen/teaser-plusplus/cloud_bin_0.ply",
            258_342,
        ),
        (
            "3dmatch-redkitchen/teaser-plusplus/cloud_bin_4.ply",
            313_395,
        ),
        ("3dmatch-redkitchen/3dsmoothnet/cloud_bin_1.ply", 268_977),
        (
            "3dmatch-redkitchen/dip/threed_match_7-scenes-redkitchen_cloud_bin_5.ply",
            313_910,
        ),
        ("3dmatch-redkitchen/mac/src.pcd", 246_311),
        ("3dmatch-redkitchen/regtr/cloud_bin_0.pth", 18_977),
        ("3dmatch-redkitchen/regtr/cloud_bin_5.pth", 19_084),
        ("3dmatch-redkitchen/predator-demo/cloud_bin_21.pth", 25_337),
        ("3dmatch-redkitchen/predator-demo/cloud_bin_34.pth", 14_602),
        ("3dmatch-redkitchen/geotransformer-demo/ref.npy", 18_977),
        ("3dmatch-redkitchen/geotransformer-demo/src.npy", 15_953),
        ("small-gicp-lidar-pair/source.ply", 69_792),
        ("small-gicp-lidar-pair/target.ply", 69_088),
    ];

    #[test]
    fn staged_clouds_load_with_manifest_counts() {
        let Some(root) = crate::testing::test_data_root() else {
            return;
        };
        for (rel, n) in STAGED {
            let c = load_cloud(&root.join(rel)).unwrap();
            assert_eq!(c.len(), n, "{rel}");
        }
    }

    /// Load times in release: `cargo test --release --no-default-features --lib
    /// io::cloud::tests::timing -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing() {
        let Some(root) = crate::testing::test_data_root() else {
            return;
        };
        for (rel, n) in STAGED {
            let p = root.join(rel);
            let _ = std::fs::read(&p).unwrap(); // warm the page cache
            let reps = 10;
            let t = std::time::Instant::now();
            for _ in 0..reps {
                assert_eq!(load_cloud(&p).unwrap().len(), n);
            }
            let ms = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
            let mb = std::fs::metadata(&p).unwrap().len() as f64 / 1e6;
            println!("{rel}: {n} points, {mb:.2} MB, {ms:.2} ms");
        }
    }
}
