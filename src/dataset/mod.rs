//! Scan pairs and datasets: two files, 3DMatch-style fragment folders with gt.log, raw RGB-D
//! sequences split into fragments, and dataset manifests.

pub mod fragment;

use crate::camera::Intrinsics;
use crate::geometry::PointCloud;
use nalgebra::Isometry3;
use std::path::PathBuf;

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
    pub intrinsics: Intrinsics,
    pub frames: Vec<RgbdFrame>,
}

#[derive(Clone, Debug)]
pub struct Scan {
    /// Human-readable name, e.g. "cloud_bin_5" or a file path.
    pub name: String,
    pub cloud: PointCloud,
    pub frames: Option<FrameSet>,
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
