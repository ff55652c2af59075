//! Parameters of a registration run. Every field is serialisable so a run can be cached,
//! reproduced from its JSON, and shown in the GUI and the CLI output.

use crate::estimate::scale::{Scaled, LIFT_RADIUS_PER_VOXEL, THRESHOLD_PER_VOXEL};
use crate::estimate::EstimatorKind;
use crate::fusion::FusionParams;
use crate::metrics::SuccessCriteria;
use crate::vfm::VfmSpec;
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
    /// SpinNet descriptors (an ONNX export of the authors' `protocol` checkpoint, made by
    /// `models/spinnet_export.sh`) at `keypoints` points drawn from the voxel-downsampled
    /// cloud; cached as the `geo-spinnet` stage.
    Spinnet {
        protocol: crate::features::spinnet::Protocol,
        #[serde(with = "crate::vfm::model_path_serde")]
        model: PathBuf,
        keypoints: usize,
    },
}

/// `--geo-features fpfh|spinnet-3dmatch|spinnet-kitti`; a SpinNet export other than the default
/// comes from `--spinnet-model`, the keypoint count from `--spinnet-keypoints`.
impl clap::ValueEnum for GeoFeatureSource {
    fn value_variants<'a>() -> &'a [Self] {
        static V: std::sync::LazyLock<[GeoFeatureSource; 3]> = std::sync::LazyLock::new(|| {
            use crate::features::spinnet::Protocol;
            [
                GeoFeatureSource::Fpfh,
                GeoFeatureSource::spinnet(Protocol::ThreeDMatch),
                GeoFeatureSource::spinnet(Protocol::Kitti),
            ]
        });
        &*V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        use clap::builder::PossibleValue;
        match self {
            GeoFeatureSource::Fpfh => {
                Some(PossibleValue::new("fpfh").help("FPFH on the voxel-downsampled clouds"))
            }
            GeoFeatureSource::Spinnet { protocol, .. } => Some(
                PossibleValue::new(match protocol {
                    crate::features::spinnet::Protocol::ThreeDMatch => "spinnet-3dmatch",
                    crate::features::spinnet::Protocol::Kitti => "spinnet-kitti",
                })
                .help(match protocol {
                    crate::features::spinnet::Protocol::ThreeDMatch => {
                        "SpinNet, the authors' 3DMatch checkpoint (indoor, 0.30 m patches)"
                    }
                    crate::features::spinnet::Protocol::Kitti => {
                        "SpinNet, the authors' KITTI checkpoint (outdoor, 2 m patches)"
                    }
                }),
            ),
            // given by their own options (--learned-source/--learned-target, --geotransformer-pkl)
            GeoFeatureSource::Files { .. } | GeoFeatureSource::GeoTransformerPkl { .. } => None,
        }
    }
}

/// SpinNet's keypoints per scan by default (`docs/spinnet.md`: chosen on every development
/// pair, 256 registering 23 of 30 where 128 registers 16).
pub const SPINNET_DEFAULT_KEYPOINTS: usize = 256;

impl From<crate::features::DescriptorName> for GeoFeatureSource {
    fn from(d: crate::features::DescriptorName) -> Self {
        match d {
            crate::features::DescriptorName::Fpfh => GeoFeatureSource::Fpfh,
            crate::features::DescriptorName::Spinnet(p) => GeoFeatureSource::spinnet(p),
        }
    }
}

impl GeoFeatureSource {
    /// The named descriptor these features are (None for features read from files).
    pub fn descriptor(&self) -> Option<crate::features::DescriptorName> {
        match self {
            GeoFeatureSource::Fpfh => Some(crate::features::DescriptorName::Fpfh),
            GeoFeatureSource::Spinnet { protocol, .. } => {
                Some(crate::features::DescriptorName::Spinnet(*protocol))
            }
            GeoFeatureSource::Files { .. } | GeoFeatureSource::GeoTransformerPkl { .. } => None,
        }
    }

    /// SpinNet with `protocol`'s default export and keypoint count.
    pub fn spinnet(protocol: crate::features::spinnet::Protocol) -> GeoFeatureSource {
        GeoFeatureSource::Spinnet {
            protocol,
            model: crate::features::spinnet::default_model_path(protocol),
            keypoints: SPINNET_DEFAULT_KEYPOINTS,
        }
    }

    /// A short name: `fpfh`, `spinnet-3dmatch`, `spinnet-kitti`, `files`, `geo-transformer-pkl`.
    pub fn name(&self) -> String {
        match self {
            GeoFeatureSource::Fpfh => "fpfh".into(),
            GeoFeatureSource::Files { .. } => "files".into(),
            GeoFeatureSource::GeoTransformerPkl { .. } => "geo-transformer-pkl".into(),
            GeoFeatureSource::Spinnet { protocol, .. } => format!("spinnet-{}", protocol.name()),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegisterParams {
    /// Voxel size (m) of the geometric keypoints; FPFH radii follow it (normals 2v, features 5v),
    /// and so do the distances that are [`Scaled::FollowVoxel`] ([`crate::estimate::scale`]).
    pub voxel: f64,
    pub geo_features: GeoFeatureSource,
    pub fusion: FusionParams,
    pub estimator: EstimatorKind,
    /// Threshold (m) for the inlier ratio of the selected correspondences under ground truth
    /// (follows the voxel: 2 v).
    #[serde(default)]
    pub inlier_threshold: Scaled<f64>,
    /// The generated-RGB branch; None runs the geometric branch alone.
    #[serde(default)]
    pub image: Option<ImageBranchParams>,
    /// When a registration counts as a success (settings written before it existed: 3DMatch's
    /// 15° / 0.30 m, what they were judged by). Not written when it is that default, so the
    /// indoor settings serialise as before (run files resume across the change).
    #[serde(default, skip_serializing_if = "is_default_success")]
    pub success: SuccessCriteria,
    /// Scale hypotheses: the whole registration at the voxels v, 2 v, ..., 2^(scales-1) v, the
    /// pose most consistent with both scans' depth views kept ([`super::scales`]); 1 = the
    /// voxel alone (not written then, so earlier run files resume).
    #[serde(default = "one_scale", skip_serializing_if = "is_one")]
    pub scales: u32,
}

fn one_scale() -> u32 {
    1
}

fn is_one(n: &u32) -> bool {
    *n == 1
}

fn is_default_success(s: &SuccessCriteria) -> bool {
    *s == SuccessCriteria::default()
}

pub use crate::dataset::preset::Preset;

/// What a preset does to the parameter types (the preset itself, its voxel and success
/// criteria, is `dataset/preset.rs`: a data set names its protocol).
impl Preset {
    /// `p` under this preset: its voxel and success criteria, every scale-aware distance
    /// following the voxel (user-set values are dropped: set them again after this).
    pub fn apply(self, p: &mut RegisterParams) {
        p.voxel = self.voxel();
        p.success = self.success();
        p.scales = self.scales();
        p.inlier_threshold = Scaled::FollowVoxel;
        match &mut p.estimator {
            EstimatorKind::Sc2Pcr(s) => {
                s.d_thre = Scaled::FollowVoxel;
                s.inlier_threshold = Scaled::FollowVoxel;
                s.max_points = self.max_points();
            }
            EstimatorKind::Ransac(r) => r.distance_threshold = Scaled::FollowVoxel,
            EstimatorKind::WeightedSvd => {}
        }
        if let Some(ib) = &mut p.image {
            ib.lift_radius = Scaled::FollowVoxel;
        }
    }

    /// The preset `p` matches, if any (voxel, success criteria and every distance following).
    pub fn of(p: &RegisterParams) -> Option<Preset> {
        Preset::ALL.into_iter().find(|pr| {
            let mut q = p.clone();
            pr.apply(&mut q);
            q == *p
        })
    }
}

impl RegisterParams {
    /// Whether a run over many pairs produces a generation missing from the cache by default:
    /// yes for every backend but a Cosmos command, whose batches take hours (a study or
    /// `generate` asks for them explicitly). Run all, the settings comparison and studies use it.
    pub fn generates_missing(&self) -> bool {
        !matches!(
            self.image.as_ref().map(|i| &i.backend),
            Some(WfmSpec::Cosmos { .. })
        )
    }

    /// The defaults of `preset`.
    pub fn preset(preset: Preset) -> RegisterParams {
        let mut p = RegisterParams::default();
        preset.apply(&mut p);
        p
    }

    /// The GT inlier-ratio threshold (m) at this voxel.
    pub fn inlier_threshold_m(&self) -> f64 {
        self.inlier_threshold.at(self.voxel, THRESHOLD_PER_VOXEL)
    }

    /// The image branch's lift radius (m) at this voxel (None: no image branch).
    pub fn lift_radius_m(&self) -> Option<f32> {
        self.image.as_ref().map(|ib| ib.lift_radius_at(self.voxel))
    }

    /// The estimator with its distances at this voxel: what runs and what its key hashes.
    pub fn estimator_resolved(&self) -> EstimatorKind {
        self.estimator.resolved(self.voxel)
    }

    /// A copy with every scale-aware distance set to its value at the voxel: what a run file
    /// records (the thresholds that were used).
    pub fn resolved(&self) -> RegisterParams {
        let mut p = self.clone();
        p.estimator = self.estimator_resolved();
        p.inlier_threshold = Scaled::Set(self.inlier_threshold_m());
        if let (Some(r), Some(ib)) = (self.lift_radius_m(), p.image.as_mut()) {
            ib.lift_radius = Scaled::Set(r);
        }
        p
    }
}

impl Default for RegisterParams {
    fn default() -> Self {
        RegisterParams {
            voxel: 0.05,
            geo_features: GeoFeatureSource::Fpfh,
            fusion: FusionParams::default(),
            estimator: EstimatorKind::default(),
            inlier_threshold: Scaled::FollowVoxel,
            image: None,
            success: SuccessCriteria::default(),
            scales: 1,
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
    /// Whether each frame is a function of its own depth (or colour) frame (the built-in
    /// shading, the oracle): no depth video, only the selected views are drawn.
    pub fn frame_by_frame(&self) -> bool {
        matches!(self, WfmSpec::Builtin | WfmSpec::Oracle)
    }

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
    /// Lifting radius (m): a point with no valid pixel this close gets no image feature
    /// (follows the keypoint voxel: 1 v; read it through [`RegisterParams::lift_radius_m`]).
    pub lift_radius: Scaled<f32>,
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
    /// ground rings in x, y, the frame's z = 0. No pose or ground truth is read.
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

impl ImageBranchParams {
    /// The lift radius (m) at keypoint voxel `voxel`.
    pub fn lift_radius_at(&self, voxel: f64) -> f32 {
        self.lift_radius.at(voxel, LIFT_RADIUS_PER_VOXEL)
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
            lift_radius: Scaled::FollowVoxel,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::{RansacParams, Sc2PcrParams};
    use crate::metrics::SuccessCriterion;

    fn sc2(p: &RegisterParams) -> Sc2PcrParams {
        match p.estimator_resolved() {
            EstimatorKind::Sc2Pcr(s) => s,
            e => panic!("not SC2-PCR: {e:?}"),
        }
    }

    #[test]
    fn outdoor_preset_is_sc2pcrs_published_kitti_configuration() {
        let p = RegisterParams::preset(Preset::Outdoor);
        let s = sc2(&p);
        // config_KITTI.json: downsample 0.3, d_thre = inlier_threshold = 0.6, num_node 8000
        assert_eq!(p.voxel, 0.3);
        assert_eq!(s.d_thre, Scaled::Set(0.6f32));
        assert_eq!(s.inlier_threshold, Scaled::Set(0.6f32));
        assert_eq!(s.max_points, 8000);
        assert_eq!(s.nms_radius, 0.10, "nms_radius does not scale");
        assert_eq!(p.inlier_threshold_m(), 0.6);
        assert_eq!(p.success.primary, SuccessCriterion::KITTI);
        assert_eq!(
            (p.success.primary.max_rre_deg, p.success.primary.max_rte_m),
            (5.0, 2.0)
        );
        let also = p.success.also.unwrap();
        assert_eq!((also.max_rre_deg, also.max_rte_m), (5.0, 0.6));
        assert_eq!(Preset::of(&p), Some(Preset::Outdoor));
    }

    #[test]
    fn outdoor_search_is_the_outdoor_preset_at_three_octaves() {
        let p = RegisterParams::preset(Preset::OutdoorSearch);
        let single = RegisterParams::preset(Preset::Outdoor);
        assert_eq!((p.scales, single.scales), (3, 1));
        assert_eq!(
            RegisterParams {
                scales: 1,
                ..p.clone()
            },
            single,
            "everything else is the outdoor preset"
        );
        assert_eq!(Preset::of(&p), Some(Preset::OutdoorSearch));
        // one scale is not written, so run files of single-voxel runs read as before
        let json = serde_json::to_value(&single).unwrap();
        assert!(json.get("scales").is_none(), "{json}");
        assert_eq!(serde_json::to_value(&p).unwrap()["scales"], 3);
        let back: RegisterParams = serde_json::from_value(json).unwrap();
        assert_eq!(back.scales, 1);
    }

    #[test]
    fn indoor_preset_is_the_3dmatch_configuration_and_the_default() {
        let p = RegisterParams::preset(Preset::Indoor);
        assert_eq!(p, RegisterParams::default());
        let s = sc2(&p);
        assert_eq!(p.voxel, 0.05);
        assert_eq!(s.d_thre, Scaled::Set(0.10f32));
        assert_eq!(s.inlier_threshold, Scaled::Set(0.10f32));
        assert_eq!(s.nms_radius, 0.10);
        assert_eq!(s.max_points, 8000);
        assert_eq!(p.inlier_threshold_m(), 0.10);
        assert_eq!(p.success.primary, SuccessCriterion::THREEDMATCH);
        assert_eq!(p.success.also, None);
        let mut q = p.clone();
        q.image = Some(ImageBranchParams::default());
        assert_eq!(q.lift_radius_m(), Some(0.05));
        assert_eq!(Preset::of(&q), Some(Preset::Indoor));
    }

    /// The indoor defaults, resolved, serialise exactly as the constants they replace did:
    /// the fusion stage's key (and so every cached result and resumed run) is unchanged.
    #[test]
    fn indoor_defaults_key_as_the_old_constants() {
        let p = RegisterParams::default();
        // the f32 fields as they always were (a JSON value holds them widened to f64)
        let old = serde_json::json!({
            "Sc2Pcr": {"inlier_threshold": 0.1f32, "d_thre": 0.1f32, "num_iterations": 10,
                       "ratio": 0.2f32, "nms_radius": 0.1f32, "max_points": 8000, "k1": 30,
                       "k2": 20, "refine_iterations": 20}
        });
        assert_eq!(serde_json::to_value(p.estimator_resolved()).unwrap(), old);
        let key = crate::pipeline::tail::key(&p, &["a", "b"]).unwrap();
        let old_key = crate::cache::CacheKey::new(
            crate::pipeline::tail::STAGE,
            crate::pipeline::tail::VERSION,
            &["a", "b"],
            &serde_json::json!({"fusion": p.fusion, "estimator": old, "inlier_threshold": 0.1}),
        )
        .unwrap();
        assert_eq!(key.hash, old_key.hash);
        let r = EstimatorKind::Ransac(RansacParams::default()).resolved(0.05);
        assert_eq!(
            serde_json::to_value(r).unwrap()["Ransac"]["distance_threshold"],
            serde_json::json!(0.075f32)
        );
        // the resolved settings read as the old ones did (numbers, no success field)
        let json = serde_json::to_value(p.resolved()).unwrap();
        assert_eq!(json["inlier_threshold"], serde_json::json!(0.1));
        assert!(json.get("success").is_none());
    }

    #[test]
    fn old_settings_read_and_a_user_value_stays_set() {
        let mut p = RegisterParams::preset(Preset::Outdoor);
        let mut json = serde_json::to_value(&p).unwrap();
        // an older file: numbers, no success criterion
        let o = json.as_object_mut().unwrap();
        o.insert("inlier_threshold".into(), serde_json::json!(0.25));
        o.remove("success");
        let q: RegisterParams = serde_json::from_value(json).unwrap();
        assert_eq!(q.inlier_threshold, Scaled::Set(0.25));
        assert_eq!(q.success, SuccessCriteria::default());
        // a value the user set is not moved by the voxel
        if let EstimatorKind::Sc2Pcr(s) = &mut p.estimator {
            s.d_thre = Scaled::Set(0.45);
        }
        p.voxel = 0.5;
        let s = sc2(&p);
        assert_eq!(s.d_thre, Scaled::Set(0.45));
        assert_eq!(s.inlier_threshold, Scaled::Set(1.0));
        assert_eq!(Preset::of(&p), None);
    }
}
