//! SpinNet (Ao et al., "SpinNet: Learning a General Surface Descriptor for 3D Point Cloud
//! Registration", CVPR 2021): a learned, rotation-invariant 32-D local descriptor, here as the
//! geometric branch's alternative to FPFH.
//!
//! The authors' `Descriptor_Net` runs in two halves. The geometry before the network is ported
//! here, one concern per file: the patch around each keypoint ([`neighbourhood`]), the local
//! reference frame of the 3DMatch protocol ([`lrf`]; none for KITTI, whose scans are
//! gravity-aligned), the spherical voxel grid ([`grid`]), the per-voxel ball query in the
//! authors' order ([`ball_query`]) and the rotation of each voxel's samples to a common azimuth
//! ([`invariant`], the authors' `var_to_invar`); [`patch`] chains them. The network after that
//! (a 1x1 convolution, a max over each voxel's samples, four cylindrical 3D convolutions and a
//! 2D head) runs through ONNX Runtime from an export of the authors' checkpoints
//! (`models/spinnet_export.sh`) in [`model`].
//!
//! The weights are research-only (the authors' repository says MIT in its LICENSE file and CC
//! BY-NC-SA 4.0 in its README): cgenreg ships neither them nor their export.

pub mod ball_query;
pub mod grid;
pub mod invariant;
pub mod keypoints;
pub mod lrf;
#[cfg(feature = "onnx")]
pub mod model;
pub mod neighbourhood;
pub mod patch;

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Which of the authors' two published settings (checkpoint and patch geometry) to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Protocol {
    /// `3DMatch_best.pkl`: 0.30 m patches, grid 9 x 40 x 80 (radial x elevation x azimuth),
    /// 0.04 m voxel balls, a local reference frame from the patch's normal.
    #[serde(rename = "3dmatch")]
    #[value(name = "3dmatch")]
    ThreeDMatch,
    /// `KITTI_best.pkl`: 2.0 m patches, grid 9 x 30 x 60, 0.3 m voxel balls, no local frame
    /// (the scan's own z axis is up).
    Kitti,
}

/// The patch geometry of one protocol (the authors' `Descriptor_Net` arguments and their test
/// scripts' patch size).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geometry {
    /// Patch radius (m): the neighbourhood and the outer shell of the grid.
    pub des_r: f32,
    pub rad_n: usize,
    pub azi_n: usize,
    pub ele_n: usize,
    /// Radius (m) of the ball around each voxel centre.
    pub voxel_r: f32,
    /// Points kept per voxel ball.
    pub voxel_sample: usize,
    /// Points per patch (the keypoint is the last).
    pub points_per_patch: usize,
    /// Whether the patch is rotated into its local reference frame first.
    pub lrf: bool,
}

impl Geometry {
    /// Voxels of the grid (radial x elevation x azimuth).
    pub fn voxels(&self) -> usize {
        self.rad_n * self.ele_n * self.azi_n
    }

    /// Floats of one grouped patch (the network's input per keypoint).
    pub fn grouped_len(&self) -> usize {
        self.voxels() * self.voxel_sample * 3
    }
}

/// The descriptor's dimension.
pub const DIM: usize = 32;

impl Protocol {
    pub const ALL: [Protocol; 2] = [Protocol::ThreeDMatch, Protocol::Kitti];

    pub fn name(self) -> &'static str {
        match self {
            Protocol::ThreeDMatch => "3dmatch",
            Protocol::Kitti => "kitti",
        }
    }

    /// `Descriptor_Net(0.30, 9, 80, 40, 0.04, 30, '3DMatch')` with 2048-point patches
    /// (`ThreeDMatch/Test/preparation.py`); `Descriptor_Net(2.0, 9, 60, 30, 0.3, 30, 'KITTI')`
    /// with 2048-point patches (`KITTI/Test/test_kitti.py`).
    pub fn geometry(self) -> Geometry {
        match self {
            Protocol::ThreeDMatch => Geometry {
                des_r: 0.30,
                rad_n: 9,
                azi_n: 80,
                ele_n: 40,
                voxel_r: 0.04,
                voxel_sample: 30,
                points_per_patch: 2048,
                lrf: true,
            },
            Protocol::Kitti => Geometry {
                des_r: 2.0,
                rad_n: 9,
                azi_n: 60,
                ele_n: 30,
                voxel_r: 0.3,
                voxel_sample: 30,
                points_per_patch: 2048,
                lrf: false,
            },
        }
    }

    /// The export's file name (`models/spinnet_export.sh` writes it).
    pub fn onnx_file(self) -> String {
        format!("spinnet-{}.onnx", self.name())
    }
}

/// Where the exports are looked for by default: `$CGENREG_SPINNET_DIR`, else the build
/// folder's `target/spinnet` (what `models/spinnet_export.sh` writes).
pub fn default_model_dir() -> PathBuf {
    match std::env::var_os("CGENREG_SPINNET_DIR") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("target")
            .join("spinnet"),
    }
}

/// The default export of `protocol`'s checkpoint.
pub fn default_model_path(protocol: Protocol) -> PathBuf {
    default_model_dir().join(protocol.onnx_file())
}
