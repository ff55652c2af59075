//! Parameters of a registration run. Every field is serialisable so a run can be cached,
//! reproduced from its JSON, and shown in the GUI and the CLI output.

use crate::estimate::EstimatorKind;
use crate::fusion::FusionParams;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where the geometric branch's features come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum GeoFeatureSource {
    /// FPFH computed here on the voxel-downsampled clouds.
    Fpfh,
    /// Precomputed learned features (points + feats), one file per scan (.npz / .pkl).
    Files { source: PathBuf, target: PathBuf },
    /// The authors' GeoTransformer pair file (reference §5): GeoTransformer's `ref` is the
    /// C-GenReg source for 3DMatch.
    GeoTransformerPkl { path: PathBuf },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegisterParams {
    /// Voxel size (m) of the geometric keypoints; FPFH radii follow it (normals 2v, features 5v).
    pub voxel: f64,
    pub geo_features: GeoFeatureSource,
    pub fusion: FusionParams,
    pub estimator: EstimatorKind,
    /// Threshold (m) for the inlier ratio of the selected correspondences under ground truth.
    pub inlier_threshold: f64,
    /// The generated-RGB branch; None runs the geometric branch alone.
    #[serde(default)]
    pub image: Option<ImageBranchParams>,
}

impl Default for RegisterParams {
    fn default() -> Self {
        RegisterParams {
            voxel: 0.05,
            geo_features: GeoFeatureSource::Fpfh,
            fusion: FusionParams::default(),
            estimator: EstimatorKind::default(),
            inlier_threshold: 0.10,
            image: None,
        }
    }
}

/// Which WFM backend produces the RGB frames of the image branch.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum WfmSpec {
    /// The dataset's real colour frames ("C-GenReg (Oracle)").
    Oracle,
    /// `builtin-depthshade-v1`: deterministic shading of the depth video, NOT a WFM.
    Builtin,
    /// An existing Cosmos output folder plus its JSONL batch spec.
    Cached { dir: PathBuf, spec: PathBuf },
    /// Run a Cosmos-Transfer1 command (argument vector, never a shell).
    Cosmos {
        command: Vec<String>,
        work_dir: PathBuf,
        timeout_s: u64,
    },
}

impl WfmSpec {
    /// Every backend, the ones with files or a command with empty ones (the user fills them).
    pub fn all() -> [WfmSpec; 4] {
        [
            WfmSpec::Oracle,
            WfmSpec::Builtin,
            WfmSpec::Cached {
                dir: PathBuf::new(),
                spec: PathBuf::new(),
            },
            WfmSpec::Cosmos {
                command: Vec::new(),
                work_dir: std::env::temp_dir().join("cgenreg-cosmos"),
                timeout_s: 3600,
            },
        ]
    }

    /// The inspector's choice text; says plainly which backends are not a WFM.
    pub fn label(&self) -> &'static str {
        match self {
            WfmSpec::Oracle => "oracle (real RGB)",
            WfmSpec::Builtin => "built-in depth shading — NOT a WFM",
            WfmSpec::Cached { .. } => "cached Cosmos output (folder + spec)",
            WfmSpec::Cosmos { .. } => "Cosmos-Transfer1 command",
        }
    }

    pub fn same_kind(&self, other: &WfmSpec) -> bool {
        std::mem::discriminant(self) == std::mem::discriminant(other)
    }
}

/// `--wfm oracle|builtin|cached|cosmos`; files and the command come from their own options.
impl clap::ValueEnum for WfmSpec {
    fn value_variants<'a>() -> &'a [Self] {
        static V: std::sync::LazyLock<[WfmSpec; 4]> = std::sync::LazyLock::new(WfmSpec::all);
        &*V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        use clap::builder::PossibleValue;
        Some(match self {
            WfmSpec::Oracle => PossibleValue::new("oracle")
                .help("The dataset's real colour frames (\"C-GenReg (Oracle)\")"),
            WfmSpec::Builtin => PossibleValue::new("builtin")
                .help("builtin-depthshade-v1: deterministic shading of the depth video. NOT a WFM"),
            WfmSpec::Cached { .. } => PossibleValue::new("cached").help(
                "An existing Cosmos output folder (--wfm-dir) with its JSONL spec (--wfm-spec)",
            ),
            WfmSpec::Cosmos { .. } => PossibleValue::new("cosmos")
                .help("Run Cosmos-Transfer1 (--cosmos-cmd, as an argument vector)"),
        })
    }
}

/// `--vfm xfeat|disk|alike|mast3r`; the model file comes from `--vfm-model`.
impl clap::ValueEnum for VfmSpec {
    fn value_variants<'a>() -> &'a [Self] {
        static V: std::sync::LazyLock<[VfmSpec; 4]> = std::sync::LazyLock::new(VfmSpec::all);
        &*V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()))
    }
}

/// Which vision foundation model describes the selected views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum VfmSpec {
    /// XFeat through ONNX (default `models/xfeat.onnx`): one descriptor grid per view.
    Xfeat {
        #[serde(with = "crate::vfm::model_path_serde")]
        model: PathBuf,
    },
    /// DISK through ONNX (default `models/disk.onnx`): dense 128-D descriptors at every pixel,
    /// sampled at the lifted pixels.
    Disk {
        #[serde(with = "crate::vfm::model_path_serde")]
        model: PathBuf,
    },
    /// ALIKE through ONNX (default `models/alike-t.onnx`, 64-D; `models/alike-n.onnx` is 128-D):
    /// dense descriptors at every pixel, sampled at the lifted pixels.
    Alike {
        #[serde(with = "crate::vfm::model_path_serde")]
        model: PathBuf,
    },
    /// A MASt3R ONNX export (reference §13 signature): descriptors of every ordered
    /// (source view, target view) pair, compared pair-conditioned (reference §8.1).
    Mast3r {
        #[serde(with = "crate::vfm::model_path_serde")]
        model: PathBuf,
    },
}

impl VfmSpec {
    /// Whether this VFM has a descriptor at every pixel (DISK, ALIKE): the one kind that reads
    /// [`ImageBranchParams::dense_stride`].
    pub fn is_dense(&self) -> bool {
        matches!(self, VfmSpec::Disk { .. } | VfmSpec::Alike { .. })
    }

    pub fn model(&self) -> &std::path::Path {
        match self {
            VfmSpec::Xfeat { model }
            | VfmSpec::Disk { model }
            | VfmSpec::Alike { model }
            | VfmSpec::Mast3r { model } => model,
        }
    }

    /// The model file, for the field that edits it.
    pub fn model_mut(&mut self) -> &mut PathBuf {
        match self {
            VfmSpec::Xfeat { model }
            | VfmSpec::Disk { model }
            | VfmSpec::Alike { model }
            | VfmSpec::Mast3r { model } => model,
        }
    }

    /// Every VFM with its default model file (MASt3R has none: no weights ship with cgenreg,
    /// so its path is empty until the user gives an export).
    pub fn all() -> [VfmSpec; 4] {
        [
            VfmSpec::default(),
            VfmSpec::Disk {
                model: crate::vfm::default_model_path("disk.onnx"),
            },
            VfmSpec::Alike {
                model: crate::vfm::default_model_path("alike-t.onnx"),
            },
            VfmSpec::Mast3r {
                model: PathBuf::new(),
            },
        ]
    }

    /// The inspector's choice text.
    pub fn label(&self) -> &'static str {
        match self {
            VfmSpec::Xfeat { .. } => "xfeat",
            VfmSpec::Disk { .. } => "disk (dense per pixel)",
            VfmSpec::Alike { .. } => "alike (dense per pixel)",
            VfmSpec::Mast3r { .. } => "mast3r (your ONNX export)",
        }
    }

    pub fn same_kind(&self, other: &VfmSpec) -> bool {
        std::mem::discriminant(self) == std::mem::discriminant(other)
    }

    pub fn name(&self) -> &'static str {
        match self {
            VfmSpec::Xfeat { .. } => "xfeat",
            VfmSpec::Disk { .. } => "disk",
            VfmSpec::Alike { .. } => "alike",
            VfmSpec::Mast3r { .. } => "mast3r",
        }
    }
}

impl Default for VfmSpec {
    fn default() -> Self {
        VfmSpec::Xfeat {
            model: crate::vfm::default_xfeat_path(),
        }
    }
}

/// The generated-RGB branch (reference §1-4, §7-8).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ImageBranchParams {
    pub backend: WfmSpec,
    pub prompt: crate::wfm::Prompt,
    pub seed: u64,
    pub vfm: VfmSpec,
    /// Views per side.
    pub k: usize,
    /// Safeguard margin m around the source/target seam of the generated video.
    pub margin: usize,
    /// Frames per fragment in the depth video (L; the reference uses 50).
    pub frames_per_fragment: usize,
    /// Lifting radius (m): a point with no valid pixel this close gets no image feature.
    pub lift_radius: f32,
    /// The virtual camera that renders depth frames for scans that have none.
    #[serde(default)]
    pub virtual_camera: VirtualCamera,
    /// f-theta cameras per LiDAR scan, evenly spaced in yaw (1: the paper's single forward
    /// camera; 2 or more cover a 360° scan, appendix B.3's extension). The depth video shows
    /// them one after the other, L / n frames each.
    #[serde(default = "one")]
    pub lidar_cameras: usize,
    /// Where the f-theta camera rig of a LiDAR scan stands: at the scan frame's origin, or at
    /// the sensor position estimated from the scan's ground rings (for clouds given in a frame
    /// other than their sensor's, e.g. PandaSet's world frame). The camera's pose is part of
    /// the `virtual-frames` key, so the cache keeps the two apart.
    #[serde(default)]
    pub lidar_origin: LidarOrigin,
    /// Cell size (pixels) through which a dense per-pixel VFM (DISK, ALIKE) is read at a lifted
    /// pixel: 1 reads its full-resolution map at the pixel; s > 1 samples the map at the
    /// centres of s x s cells (each unit) and interpolates between them bilinearly. Chosen on
    /// the development set (`docs/ablation.md`). XFeat (its own H/8 grid) and MASt3R do not read
    /// it. Settings written before this field existed read 4: their dense rows ran that way.
    #[serde(default = "four")]
    pub dense_stride: u32,
}

fn one() -> usize {
    1
}

fn four() -> u32 {
    4
}

/// [`ImageBranchParams::dense_stride`]'s default (the development set's choice).
pub const DEFAULT_DENSE_STRIDE: u32 = 1;

/// How depth frames are made for a scan that is only a point cloud (paper §3.1, appendix B.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum VirtualCamera {
    /// f-theta for LiDAR-like scans (the cloud carries intensity, as LiDAR formats do),
    /// pinhole trajectory otherwise.
    #[default]
    Auto,
    /// A pinhole camera moving along an arc around the cloud (RGB-D-like scans).
    Pinhole,
    /// One forward-facing f-theta camera at the sensor origin, 1280x640, 180 degrees (LiDAR).
    Ftheta,
}

/// Where the virtual f-theta camera rig of a LiDAR scan stands (its axes are always the scan
/// frame's: the yaw is not estimated).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum LidarOrigin {
    /// At the origin of the scan's coordinate frame: right for a scan in its sensor frame.
    #[default]
    ScanOrigin,
    /// At the sensor position estimated from the scan itself: the centre of its innermost
    /// ground rings in x, y, the frame's z = 0 ([`crate::camera::sensor_origin`]). No pose or
    /// ground truth is read.
    Estimated,
}

impl LidarOrigin {
    pub const ALL: [LidarOrigin; 2] = [LidarOrigin::ScanOrigin, LidarOrigin::Estimated];

    pub fn label(self) -> &'static str {
        match self {
            LidarOrigin::ScanOrigin => "scan frame's origin",
            LidarOrigin::Estimated => "estimated from the ground rings",
        }
    }
}

impl VirtualCamera {
    /// The camera this choice gives for `cloud`.
    pub fn resolve(self, cloud: &crate::geometry::PointCloud) -> VirtualCamera {
        match self {
            VirtualCamera::Auto if cloud.intensity.is_some() => VirtualCamera::Ftheta,
            VirtualCamera::Auto => VirtualCamera::Pinhole,
            v => v,
        }
    }
}

impl Default for ImageBranchParams {
    fn default() -> Self {
        ImageBranchParams {
            backend: WfmSpec::Builtin,
            prompt: crate::wfm::Prompt::from_preset(crate::wfm::PromptPreset::SceneSpecific),
            seed: 0,
            vfm: VfmSpec::default(),
            k: 4,
            margin: 3,
            frames_per_fragment: 50,
            lift_radius: 0.05,
            virtual_camera: VirtualCamera::Auto,
            lidar_cameras: 1,
            lidar_origin: LidarOrigin::ScanOrigin,
            dense_stride: DEFAULT_DENSE_STRIDE,
        }
    }
}

/// `s` with the image branch switched to the cached Cosmos output in `dir` and its spec
/// ([`crate::wfm::cached::find_cosmos_spec`]); everything else unchanged.
pub fn cosmos_output_settings(
    p: &RegisterParams,
    dir: &std::path::Path,
) -> crate::Result<RegisterParams> {
    let spec = crate::wfm::cached::find_cosmos_spec(dir)?;
    let mut p = p.clone();
    p.image
        .get_or_insert_with(ImageBranchParams::default)
        .backend = WfmSpec::Cached {
        dir: dir.to_path_buf(),
        spec,
    };
    Ok(p)
}
