//! Pipeline options shared by `register`, `bench` and the GUI's command line.

//!
//! Every choice is the pipeline's own type (clap's `ValueEnum` is implemented on them), so
//! an option means the same thing here, in the inspector and in a run's JSON.

use crate::cache::Cache;
use crate::estimate::scale::Scaled;
use crate::estimate::EstimatorKind;
use crate::features::DescriptorName;
use crate::fusion::calibrate::Calibration;
use crate::fusion::fuse::FusionMode;
use crate::fusion::select::Selection;
use crate::pipeline::params::{
    GeoFeatureSource, ImageBranchParams, LidarOrigin, Preset, RegisterParams, VirtualCamera,
    WfmSpec,
};
use crate::vfm::VfmSpec;
use crate::wfm::{Prompt, PromptPreset};
use clap::Args;
use std::path::PathBuf;

/// A finite number > 0 (lengths, radii); clap names the option in the error.
fn positive_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!(
            "must be a positive length in metres, got {}",
            s.trim()
        )),
    }
}

fn positive_f32(s: &str) -> Result<f32, String> {
    positive_f64(s).map(|v| v as f32)
}

/// A finite number > 0 that is not a length (softmax temperatures).
fn positive_number(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && (v as f32) > 0.0 => Ok(v as f32),
        _ => Err(format!("must be a positive number, got {}", s.trim())),
    }
}

/// A probability strictly between 0 and 1 (the Noisy-AND prior).
fn probability(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v < 1.0 => Ok(v),
        _ => Err(format!(
            "must be a probability between 0 and 1 (exclusive), got {}",
            s.trim()
        )),
    }
}

/// A whole number of at least `min`: one message for every value that is not one (-1, 1.5,
/// "x", 2^70), naming what is accepted and what was given.
fn whole_number(s: &str, min: usize) -> Result<usize, String> {
    let t = s.trim();
    match t.parse::<usize>() {
        Ok(n) if n >= min => Ok(n),
        Ok(n) => Err(format!("must be a whole number of at least {min}, got {n}")),
        Err(_) if t.parse::<i128>().is_ok_and(|v| v > 0) => Err(format!(
            "must be a whole number of at least {min} and at most {}, got {t}",
            usize::MAX
        )),
        Err(_) => Err(format!("must be a whole number of at least {min}, got {t}")),
    }
}

/// A count of at least 1 (views per side, top-k).
fn count_from_1(s: &str) -> Result<usize, String> {
    whole_number(s, 1)
}

/// A count of at least 0 (the safeguard margin).
fn count_from_0(s: &str) -> Result<usize, String> {
    whole_number(s, 0)
}

/// Frames per fragment: 1 ..= the frame limit (checked before any work starts; every frame
/// is rendered, written and generated, so 100,000 would run for hours and fill the disk).
fn frame_count(s: &str) -> Result<usize, String> {
    let n = whole_number(s, 1)?;
    let max = crate::io::limits::max_frames();
    if n > max {
        return Err(format!(
            "{n} frames per fragment exceeds the limit of {max} (set {}=N to allow more)",
            crate::io::limits::ENV_MAX_FRAMES
        ));
    }
    Ok(n)
}

#[derive(Args, Debug, Clone)]
pub struct PipelineArgs {
    /// Protocol to start from: indoor (3DMatch: voxel 0.05 m, thresholds 0.10 m, success
    /// 15°/0.30 m), outdoor (KITTI: voxel 0.3 m, thresholds 0.6 m, success 5°/2 m with
    /// SC2-PCR's 5°/0.6 m beside it) or outdoor-search (outdoor at the voxels 0.3, 0.6 and
    /// 1.2 m, the pose most consistent with both scans' range views kept: LiDAR of unknown
    /// scale). Default: the manifest's `preset`, else indoor.
    #[arg(long, value_enum)]
    pub preset: Option<Preset>,
    /// Scale hypotheses: register at the voxels v, 2v, ..., 2^(N-1) v (every distance that
    /// follows the voxel with it) and keep the pose most consistent with both scans' depth
    /// views (sensor frames, else 360° range images at each scan's estimated sensor position;
    /// for LiDAR). 1: the voxel alone. Default: the preset's (3 for outdoor-search, else 1).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=6))]
    pub scales: Option<u32>,
    /// Keypoint voxel size in metres (default: the preset's). FPFH radii follow it (normals
    /// 2v, features 5v), and so do the thresholds not set below (2v) and the lift radius (1v).
    #[arg(long, value_parser = positive_f64, allow_hyphen_values = true)]
    pub voxel: Option<f64>,
    /// SC2-PCR's inlier threshold and the GT inlier-ratio threshold, metres (default: 2 x voxel).
    #[arg(long, value_parser = positive_f64, allow_hyphen_values = true)]
    pub inlier_threshold: Option<f64>,
    /// SC2-PCR's compatibility threshold d_thre, metres (default: 2 x voxel).
    #[arg(long, value_parser = positive_f64, allow_hyphen_values = true)]
    pub d_thre: Option<f64>,
    /// Learned features for the source scan (.npz with points/feats, or .pkl); needs --learned-target.
    #[arg(long, requires = "learned_target")]
    pub learned_source: Option<PathBuf>,
    #[arg(long, requires = "learned_source")]
    pub learned_target: Option<PathBuf>,
    /// The authors' GeoTransformer pair feature file (.pkl, reference §5).
    #[arg(long, conflicts_with = "learned_source")]
    pub geotransformer_pkl: Option<PathBuf>,
    /// The geometric branch's features (default fpfh). SpinNet needs an ONNX export of the
    /// authors' checkpoint (models/spinnet_export.sh writes target/spinnet/; research-only
    /// weights, not shipped) and runs at --spinnet-keypoints points per scan.
    #[arg(long, value_enum, conflicts_with_all = ["learned_source", "geotransformer_pkl"])]
    pub geo_features: Option<GeoFeatureSource>,
    /// The SpinNet ONNX export (default: target/spinnet/spinnet-<protocol>.onnx, or
    /// $CGENREG_SPINNET_DIR/spinnet-<protocol>.onnx).
    #[arg(long, requires = "geo_features")]
    pub spinnet_model: Option<PathBuf>,
    /// SpinNet keypoints per scan, drawn from the voxel-downsampled cloud (default 256, chosen on
    /// the development pairs; docs/spinnet.md).
    #[arg(long, requires = "geo_features", value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub spinnet_keypoints: Option<u64>,
    /// Calibration of both branches (row: the paper's eq. 5; dual: the reference code's).
    #[arg(long, value_enum, default_value = "row")]
    pub calibration: Calibration,
    /// Softmax temperature of the image branch.
    #[arg(long, default_value_t = 0.1, value_parser = positive_number, allow_hyphen_values = true)]
    pub tau_img: f32,
    /// Softmax temperature of the geometric branch.
    #[arg(long, default_value_t = 0.1, value_parser = positive_number, allow_hyphen_values = true)]
    pub tau_geo: f32,
    /// Fusion of the two branches. Default: `visibility` when the image branch runs (the
    /// union's, the geometric branch's, Noisy-AND's and the image branch's poses; the one most
    /// consistent with both scans' depth views is kept), Noisy-AND with `--reference` (the
    /// authors' code), `geometry` without the image branch.
    #[arg(long, value_enum)]
    pub fusion: Option<FusionMode>,
    /// Noisy-AND prior; default 1/(N*M).
    #[arg(long, value_parser = probability, allow_hyphen_values = true)]
    pub prior: Option<f64>,
    /// Correspondence selection. Default: `nn` when only the geometric branch runs (the
    /// SC2-PCR FPFH protocol), `mutual` when branches are fused (the paper).
    #[arg(long, value_enum)]
    pub selection: Option<Selection>,
    /// k of --selection topk.
    #[arg(long, default_value_t = 8000, value_parser = count_from_1, allow_hyphen_values = true)]
    pub topk: usize,
    #[arg(long, value_enum, default_value = "sc2pcr")]
    pub estimator: EstimatorKind,
    /// Reproduce the authors' code: dual softmax, global top-8000, f32 Noisy-AND as written,
    /// SC2-PCR in score order (the authors' tie-breaking).
    #[arg(long)]
    pub reference: bool,
}

impl PipelineArgs {
    /// The geometric features these options name: learned feature files, else
    /// `--geo-features`, else `manifest` (a data set's `geo_features`), else FPFH; a SpinNet
    /// choice takes `--spinnet-model` and `--spinnet-keypoints`.
    pub fn geo_features_or(&self, manifest: Option<DescriptorName>) -> GeoFeatureSource {
        let mut g = match (
            &self.learned_source,
            &self.learned_target,
            &self.geotransformer_pkl,
        ) {
            (Some(s), Some(t), _) => GeoFeatureSource::Files {
                source: s.clone(),
                target: t.clone(),
            },
            (_, _, Some(pkl)) => GeoFeatureSource::GeoTransformerPkl { path: pkl.clone() },
            _ => match (&self.geo_features, manifest) {
                (Some(g), _) => g.clone(),
                (None, Some(d)) => GeoFeatureSource::from(d),
                (None, None) => GeoFeatureSource::Fpfh,
            },
        };
        if let GeoFeatureSource::Spinnet {
            model, keypoints, ..
        } = &mut g
        {
            if let Some(m) = &self.spinnet_model {
                *model = m.clone();
            }
            if let Some(k) = self.spinnet_keypoints {
                *keypoints = k as usize;
            }
        }
        g
    }

    /// The run's parameters; `manifest_preset` is the data set's own (`preset` in its
    /// manifest), used when `--preset` is not given.
    pub fn to_params(&self, image_branch: bool, manifest_preset: Option<Preset>) -> RegisterParams {
        let mut p = RegisterParams {
            geo_features: self.geo_features_or(None),
            ..RegisterParams::default()
        };
        // --reference: the authors' dual softmax and global top-8000 (temperatures and mode
        // still from their options); otherwise the paper's choices or the given ones.
        let (cal, sel) = if self.reference {
            (
                Calibration::DualSoftmax { tau: 0.1 },
                Selection::TopK(crate::fusion::select::REFERENCE_TOP_K),
            )
        } else {
            let sel = self
                .selection
                .unwrap_or(Selection::default_for(image_branch));
            let sel = match sel {
                Selection::TopK(_) => Selection::TopK(self.topk),
                s => s,
            };
            (self.calibration, sel)
        };
        p.fusion.calibration_img = cal.with_tau(self.tau_img);
        p.fusion.calibration_geo = cal.with_tau(self.tau_geo);
        p.fusion.mode = self
            .fusion
            .unwrap_or(FusionMode::default_for(image_branch, self.reference));
        p.fusion.selection = sel;
        p.fusion.exact_reference = self.reference;
        p.fusion.prior = self.prior;
        p.estimator = self.estimator.clone();
        crate::pipeline::manifest_settings::resolve_preset(self.preset, manifest_preset)
            .apply(&mut p);
        self.apply_overrides(&mut p);
        // --reference: SC2-PCR in the authors' score order (their tie-breaking)
        if let (true, crate::estimate::EstimatorKind::Sc2Pcr(s)) =
            (self.reference, &mut p.estimator)
        {
            s.score_order = true;
        }
        p
    }

    /// The explicit --voxel, --inlier-threshold and --d-thre over `p`.
    pub fn apply_overrides(&self, p: &mut RegisterParams) {
        if let Some(v) = self.voxel {
            p.voxel = v;
        }
        if let Some(n) = self.scales {
            p.scales = n;
        }
        if let Some(t) = self.inlier_threshold {
            p.inlier_threshold = Scaled::Set(t);
        }
        match &mut p.estimator {
            crate::estimate::EstimatorKind::Sc2Pcr(s) => {
                if let Some(t) = self.inlier_threshold {
                    s.inlier_threshold = Scaled::Set(t as f32);
                }
                if let Some(d) = self.d_thre {
                    s.d_thre = Scaled::Set(d as f32);
                }
            }
            // RANSAC's inlier distance follows the voxel (1.5 v); the GUI sets it
            crate::estimate::EstimatorKind::Ransac(_)
            | crate::estimate::EstimatorKind::WeightedSvd => {}
        }
    }
}

/// Options of the generated-RGB image branch and of the stage cache.
#[derive(Args, Debug, Clone)]
pub struct ImageArgs {
    /// WFM backend of the image branch; absent = geometric branch only.
    #[arg(long, value_enum)]
    pub wfm: Option<WfmSpec>,
    /// Cosmos output folder for --wfm cached.
    #[arg(long)]
    pub wfm_dir: Option<PathBuf>,
    /// JSONL batch spec for --wfm cached.
    #[arg(long)]
    pub wfm_spec: Option<PathBuf>,
    /// Cosmos command for --wfm cosmos: program and arguments, one per occurrence
    /// (`--cosmos-cmd torchrun --cosmos-cmd ...`); never run through a shell.
    #[arg(long, num_args = 1, allow_hyphen_values = true)]
    pub cosmos_cmd: Vec<String>,
    /// Job folder for --wfm cosmos.
    #[arg(long)]
    pub cosmos_work_dir: Option<PathBuf>,
    /// Timeout of the Cosmos command, seconds.
    #[arg(long, default_value_t = 3600)]
    pub cosmos_timeout: u64,
    /// Prompt preset (paper's four categories).
    #[arg(long, value_enum, default_value = "scene")]
    pub prompt_preset: PromptPreset,
    /// Scene description replacing the preset's (the shared prefix is kept).
    #[arg(long)]
    pub prompt: Option<String>,
    /// Generation seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Vision foundation model: xfeat (per-image, H/8 grid; default models/xfeat.onnx), disk or
    /// alike (per-image, dense per pixel; default models/disk.onnx, models/alike-t.onnx) or mast3r
    /// (pair-conditioned; needs --vfm-model, an export made with models/export_mast3r.py).
    #[arg(long, value_enum, default_value = "xfeat")]
    pub vfm: VfmSpec,
    /// The VFM's ONNX model file.
    #[arg(long)]
    pub vfm_model: Option<PathBuf>,
    /// Views per side.
    #[arg(long, default_value_t = 4, value_parser = count_from_1, allow_hyphen_values = true)]
    pub k: usize,
    /// Safeguard margin m (frames dropped on each side of the source/target seam).
    #[arg(long, default_value_t = 3, value_parser = count_from_0, allow_hyphen_values = true)]
    pub margin: usize,
    /// Frames per fragment in the depth video (L); at most 1000 unless CGENREG_MAX_FRAMES
    /// allows more.
    #[arg(long, default_value_t = 50, value_parser = frame_count, allow_hyphen_values = true)]
    pub frames: usize,
    /// Lifting radius in metres (default: the keypoint voxel).
    #[arg(long, value_parser = positive_f32, allow_hyphen_values = true)]
    pub lift_radius: Option<f32>,
    /// Virtual camera for scans with no depth frames: f-theta for LiDAR-like clouds (they
    /// carry intensity) and a pinhole trajectory otherwise (auto), or force one.
    #[arg(long, value_enum, default_value = "auto")]
    pub virtual_camera: VirtualCamera,
    /// f-theta cameras per LiDAR scan, evenly spaced in yaw (1 = the paper's single forward
    /// camera; 2 or more cover a 360° scan).
    #[arg(long, default_value_t = 1)]
    pub lidar_cameras: usize,
    /// Where the f-theta cameras of a LiDAR scan stand: scan-origin (the origin of the scan's
    /// frame: right for a scan in its sensor frame) or estimated (the sensor position found
    /// from the scan's own ground rings; for scans in a world frame).
    #[arg(long, value_enum, default_value = "scan-origin")]
    pub lidar_origin: LidarOrigin,
    /// Cell size (pixels) at which DISK / ALIKE are read at a lifted pixel: 1 = the pixel of the
    /// full-resolution map; s > 1 = bilinear between the centres of s x s cells.
    #[arg(long, default_value_t = crate::pipeline::params::DEFAULT_DENSE_STRIDE,
          value_parser = clap::value_parser!(u32).range(1..=64))]
    pub dense_stride: u32,
    /// Stage cache directory (default: $CGENREG_CACHE or ~/.cache/cgenreg).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Compute every stage in memory; read and write no cache.
    #[arg(long, conflicts_with = "cache_dir")]
    pub no_cache: bool,
}

impl ImageArgs {
    pub fn to_image_params(&self) -> crate::Result<Option<ImageBranchParams>> {
        let Some(wfm) = &self.wfm else {
            return Ok(None);
        };
        let backend = match wfm {
            WfmSpec::Cached { .. } => match (&self.wfm_dir, &self.wfm_spec) {
                (Some(d), Some(s)) => WfmSpec::Cached {
                    dir: d.clone(),
                    spec: s.clone(),
                },
                _ => {
                    return Err(crate::Error::Usage(
                        "--wfm cached needs --wfm-dir (Cosmos output folder) and --wfm-spec (its JSONL)"
                            .into(),
                    ))
                }
            },
            WfmSpec::Cosmos { .. } => {
                if self.cosmos_cmd.is_empty() {
                    return Err(crate::Error::Usage(
                        "--wfm cosmos needs --cosmos-cmd PROGRAM [--cosmos-cmd ARG ...]".into(),
                    ));
                }
                WfmSpec::Cosmos {
                    command: self.cosmos_cmd.clone(),
                    work_dir: self
                        .cosmos_work_dir
                        .clone()
                        .unwrap_or_else(|| std::env::temp_dir().join("cgenreg-cosmos")),
                    timeout_s: self.cosmos_timeout,
                }
            }
            w => w.clone(),
        };
        let mut prompt = Prompt::from_preset(self.prompt_preset);
        if let Some(s) = &self.prompt {
            prompt.scene = s.clone();
        }
        let mut vfm = self.vfm.clone();
        match (&mut vfm, &self.vfm_model) {
            (v, Some(p)) => *v.model_mut() = p.clone(),
            (VfmSpec::Mast3r { .. }, None) => {
                return Err(crate::Error::Usage(
                    "--vfm mast3r needs --vfm-model FILE.onnx (export it with \
                     models/export_mast3r.py; no MASt3R weights ship with cgenreg)"
                        .into(),
                ))
            }
            _ => {}
        }
        Ok(Some(ImageBranchParams {
            backend,
            prompt,
            seed: self.seed,
            vfm,
            k: self.k,
            margin: self.margin,
            frames_per_fragment: self.frames,
            lift_radius: self.lift_radius.map_or(Scaled::FollowVoxel, Scaled::Set),
            virtual_camera: self.virtual_camera,
            lidar_cameras: self.lidar_cameras,
            lidar_origin: self.lidar_origin,
            dense_stride: self.dense_stride,
        }))
    }

    /// The run's parameters (pipeline options + this image branch) and the stage cache (None
    /// with --no-cache; geometry alone uses it too, for `geo-fpfh`).
    pub fn params_and_cache(
        &self,
        pipeline: &PipelineArgs,
    ) -> crate::Result<(crate::pipeline::RegisterParams, Option<Cache>)> {
        self.params_and_cache_for(pipeline, &ManifestSettings::default())
    }

    /// [`Self::params_and_cache`] for a data set whose manifest names `manifest_preset` and,
    /// as `scene_prompt`, its own scene description: the scene-specific prompt (the default)
    /// describes that scene unless `--prompt` gives one.
    pub fn params_and_cache_for(
        &self,
        pipeline: &PipelineArgs,
        manifest: &ManifestSettings,
    ) -> crate::Result<(crate::pipeline::RegisterParams, Option<Cache>)> {
        let ManifestSettings {
            preset: manifest_preset,
            scene_prompt,
            geo_features,
        } = manifest;
        let scene_prompt = scene_prompt.as_deref();
        let mut params = pipeline.to_params(self.wfm.is_some(), *manifest_preset);
        params.geo_features = pipeline.geo_features_or(*geo_features);
        params.image = self.to_image_params()?;
        if let (Some(ib), Some(scene), None, PromptPreset::SceneSpecific) = (
            params.image.as_mut(),
            scene_prompt,
            &self.prompt,
            self.prompt_preset,
        ) {
            ib.prompt.scene = scene.to_owned();
        }
        // Geometry alone is cached too (stage `geo-fpfh`), so the cache opens either way.
        let cache = self.open_cache()?;
        Ok((params, cache))
    }

    /// The stage cache that keeps fragments rebuilt from raw RGB-D frames (None with
    /// `--no-cache`); opened whether or not the image branch is on.
    pub fn fragment_cache(&self) -> crate::Result<Option<Cache>> {
        self.open_cache()
    }

    pub fn open_cache(&self) -> crate::Result<Option<Cache>> {
        if self.no_cache {
            return Ok(None);
        }
        let dir = self
            .cache_dir
            .clone()
            .unwrap_or_else(crate::cache::default_cache_dir);
        Ok(Some(Cache::open(dir)?))
    }
}

/// What a data set's manifest sets for its runs (the library's one resolution of them).
pub use crate::pipeline::manifest_settings::ManifestSettings;

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        p: PipelineArgs,
    }

    fn sc2(args: &[&str]) -> Option<crate::estimate::Sc2PcrParams> {
        let cli = Cli::try_parse_from(std::iter::once("x").chain(args.iter().copied())).unwrap();
        match cli.p.to_params(false, None).estimator {
            EstimatorKind::Sc2Pcr(p) => Some(p),
            _ => None,
        }
    }

    /// A manifest's `geo_features` applies unless an option names the features.
    #[test]
    fn a_manifests_geo_features_apply_unless_an_option_names_them() {
        use crate::features::spinnet::Protocol;
        let geo = |args: &[&str], m: Option<DescriptorName>| {
            let cli =
                Cli::try_parse_from(std::iter::once("x").chain(args.iter().copied())).unwrap();
            cli.p.geo_features_or(m)
        };
        let kitti = Some(DescriptorName::Spinnet(Protocol::Kitti));
        assert_eq!(geo(&[], None), GeoFeatureSource::Fpfh);
        assert_eq!(geo(&[], kitti), GeoFeatureSource::spinnet(Protocol::Kitti));
        assert_eq!(
            geo(&["--geo-features", "fpfh"], kitti),
            GeoFeatureSource::Fpfh
        );
        // SpinNet's own options need --geo-features (they would be ignored with FPFH)
        match geo(
            &[
                "--geo-features",
                "spinnet-kitti",
                "--spinnet-keypoints",
                "64",
            ],
            None,
        ) {
            GeoFeatureSource::Spinnet {
                protocol,
                keypoints,
                ..
            } => assert_eq!((protocol, keypoints), (Protocol::Kitti, 64)),
            g => panic!("{g:?}"),
        }
        for d in DescriptorName::ALL {
            assert_eq!(GeoFeatureSource::from(d).descriptor(), Some(d));
            assert_eq!(DescriptorName::parse(d.name()), Some(d));
        }
    }

    /// `--reference` runs SC2-PCR in the authors' score order; by default (and for the other
    /// estimators) nothing changes.
    #[test]
    fn reference_sets_sc2pcr_score_order() {
        assert!(sc2(&["--reference"]).unwrap().score_order);
        assert!(!sc2(&[]).unwrap().score_order);
        assert_eq!(sc2(&[]).unwrap(), crate::estimate::Sc2PcrParams::default());
        assert!(sc2(&["--reference", "--estimator", "ransac"]).is_none());
    }
}
