//! Scan pairs and datasets: two files, 3DMatch-style fragment folders with gt.log, raw RGB-D
//! sequences split into fragments, and dataset manifests.

pub mod fragment;
pub mod fragment_cache;
pub mod manifest;
pub mod official;
pub mod open;
pub mod preset;
pub mod repose;
pub mod rgbd_sequence;
pub mod threedmatch;

pub use manifest::{Dataset, FragmentSource, FragmentSpec, PairSpec};

use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use nalgebra::Isometry3;
use std::path::{Path, PathBuf};

/// One RGB-D frame a scan was made from. Images are loaded on demand.
#[derive(Clone, Debug)]
pub struct RgbdFrame {
    pub index: usize,
    pub depth_path: PathBuf,
    pub color_path: Option<PathBuf>,
    /// Pose of this frame's camera in the scan's coordinates (the fragment's first frame):
    /// p_scan = scan_from_camera * p_camera.
    pub scan_from_camera: Isometry3<f64>,
}

/// The frames a scan was fused from, when the source provides them.
#[derive(Clone, Debug)]
pub struct FrameSet {
    /// The camera of every frame: pinhole for RGB-D sensors and virtual pinhole trajectories,
    /// f-theta for the virtual camera of a LiDAR scan.
    pub camera: CameraModel,
    pub frames: Vec<RgbdFrame>,
    /// Where the frames' cameras stand: whether an empty depth ray is one the sensor cast.
    pub origin: ViewOrigin,
}

/// Where a frame set's cameras stand. A depth pixel says "this ray is empty up to depth d" only
/// along a ray the sensor cast; in a virtual view an empty pixel is only where the cloud has no
/// points. The `visibility` fusion's report says which views it compared poses in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ViewOrigin {
    /// The sensor's own frames (an RGB-D fragment's).
    Sensor,
    /// Range images rendered at a LiDAR scan's sensor position (its scan origin or the
    /// estimated one): the sensor's rays, resampled.
    SensorPosition,
    /// A virtual trajectory around a cloud-only scan: rays no sensor cast.
    Virtual,
}

impl ViewOrigin {
    /// Whether free space in these views is evidence (the sensor's rays).
    pub fn is_sensor(self) -> bool {
        matches!(self, ViewOrigin::Sensor | ViewOrigin::SensorPosition)
    }

    pub fn label(self) -> &'static str {
        match self {
            ViewOrigin::Sensor => "sensor frames",
            ViewOrigin::SensorPosition => "range images at the sensor",
            ViewOrigin::Virtual => "virtual views",
        }
    }
}

#[derive(Clone, Debug)]
pub struct Scan {
    /// Human-readable name, e.g. "cloud_bin_5" or a file path.
    pub name: String,
    pub cloud: PointCloud,
    pub frames: Option<FrameSet>,
    /// What reading the scan changed or found (dropped NaN rows, far outliers), reported with
    /// every result of a pair that uses it.
    pub notes: Vec<String>,
}

/// A registration problem: register `source` onto `target`.
#[derive(Clone, Debug)]
pub struct ScanPair {
    /// Stable id, e.g. "redkitchen/0-5" (target 0, source 5 as in gt.log `0 5`).
    pub id: String,
    pub source: Scan,
    pub target: Scan,
    /// Ground truth when known: p_target = T * p_source.
    pub gt_target_from_source: Option<Isometry3<f64>>,
}

/// Read a 4x4 ground-truth matrix `target_from_source` (p_target = T * p_source) from a text
/// file (16 whitespace-separated numbers, row-major) or a `.npy` array of shape (4, 4).
pub fn read_gt_matrix(path: &Path) -> Result<Isometry3<f64>> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    if !is_npy {
        return crate::camera::camera_txt::read_pose(path);
    }
    let a = crate::io::npy::read_npy(path)?;
    let v = a.to_f64();
    if a.rows_cols() != Some((4, 4)) || v.len() != 16 {
        return Err(Error::format(
            path,
            "shape",
            "a 4x4 matrix",
            format!("{:?} ({} values)", a.rows_cols(), v.len()),
        ));
    }
    crate::geometry::transform::isometry_from_matrix(&nalgebra::Matrix4::from_row_slice(&v))
        .ok_or_else(|| {
            Error::format(
                path,
                "matrix",
                "a finite rigid 4x4 transform (last row 0 0 0 1)",
                crate::geometry::transform::rigidity_problem(&nalgebra::Matrix4::from_row_slice(
                    &v,
                )),
            )
        })
}

/// A pair from two point-cloud files, with optional ground truth `target_from_source`.
/// The id is `"files/<target stem>-<source stem>"`.
pub fn pair_from_files(source: &Path, target: &Path, gt: Option<&Path>) -> Result<ScanPair> {
    let load = |p: &Path| -> Result<Scan> {
        let (cloud, notes) = crate::io::cloud::load_cloud_noted(p)?;
        if cloud.is_empty() {
            return Err(Error::Invalid(format!(
                "{}: empty point cloud",
                p.display()
            )));
        }
        Ok(Scan {
            name: p.display().to_string(),
            cloud,
            frames: None,
            notes,
        })
    };
    let (s, t) = rayon::join(|| load(source), || load(target));
    let gt = gt.map(read_gt_matrix).transpose()?;
    let stem = |p: &Path| {
        p.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    Ok(ScanPair {
        id: format!("files/{}-{}", stem(target), stem(source)),
        source: s?,
        target: t?,
        gt_target_from_source: gt,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_ply(path: &Path, n: usize) {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        )
        .into_bytes();
        for i in 0..n {
            for v in [i as f32 * 0.1, 1.0, 2.0] {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        std::fs::write(path, b).unwrap();
    }

    #[test]
    fn pair_from_two_files_with_text_gt() {
        let d = tempfile::tempdir().unwrap();
        let (s, t, g) = (
            d.path().join("s.ply"),
            d.path().join("t.ply"),
            d.path().join("gt.txt"),
        );
        write_ply(&s, 5);
        write_ply(&t, 7);
        std::fs::write(&g, "1 0 0 0.25\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        let p = pair_from_files(&s, &t, Some(&g)).unwrap();
        assert_eq!((p.source.cloud.len(), p.target.cloud.len()), (5, 7));
        assert_eq!(p.id, "files/t-s");
        assert_eq!(p.gt_target_from_source.unwrap().translation.vector.x, 0.25);
        std::fs::write(&g, "1 0 0\n").unwrap();
        let e = pair_from_files(&s, &t, Some(&g)).unwrap_err().to_string();
        assert!(
            e.contains("gt.txt") && e.contains("4 rows of 4 numbers"),
            "{e}"
        );
        let e = pair_from_files(&s, &t, Some(&d.path().join("gt.npy")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("gt.npy"), "{e}");
        // a 4x4 .npy ground truth, row-major
        let mut m = [0f32; 16];
        for k in 0..4 {
            m[k * 5] = 1.0;
        }
        m[3] = 0.5;
        let npy = d.path().join("gt.npy");
        std::fs::write(&npy, crate::io::npy::encode_npy_f32(&[4, 4], &m)).unwrap();
        let p = pair_from_files(&s, &t, Some(&npy)).unwrap();
        assert_eq!(p.gt_target_from_source.unwrap().translation.vector.x, 0.5);
        std::fs::write(&npy, crate::io::npy::encode_npy_f32(&[3, 4], &m[..12])).unwrap();
        let e = read_gt_matrix(&npy).unwrap_err().to_string();
        assert!(e.contains("gt.npy") && e.contains("4x4"), "{e}");
    }
}
