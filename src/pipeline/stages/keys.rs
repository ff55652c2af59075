//! Which stages a parameter change invalidates, from the stages' own key functions.
//!
//! [`StageKeys::compute`] evaluates every stage's key for one pair and one parameter set with
//! the functions the stages run with (`geo::key`, `depth_video::plan`, `generation::plan`,
//! `view_select::key`, `vfm::key`, `lift::key_for`, `image_points::key`, `pair_vfm::key`,
//! `virtual_frames::keys`, `tail::key`), without computing any stage: it hashes input files
//! (the depth frames, the model file) and reads what the cache already holds.
//! [`StageKeys::invalidated_by`] lists the stages whose keys differ between two parameter sets,
//! earliest first; [`invalidated`] does both.
//!
//! Some keys read a stage's *output*: the generation is keyed by the depth video's content
//! hash, the view selection by the generated video's length, the lift by the generated frames'
//! size, and for point-cloud-only scans everything after the virtual frames by the rendered
//! depth files. These are read from the cache; when the producing stage's entry is not there
//! (a new prompt, no cache), the keys after it are not known before it runs, and those stages
//! count as invalidated.

use super::depth_video::{self, frames_of};
use super::lift::LiftInput;
use super::virtual_frames::{self, with_virtual_frames, FrameStore};
use super::{generation, geo, image_points, lift, pair_vfm, vfm, view_select};
use crate::cache::{Cache, CacheKey};
use crate::dataset::{FrameSet, Scan, ScanPair};
use crate::error::Result;
use crate::pipeline::memo::Memo;
use crate::pipeline::params::{GeoFeatureSource, ImageBranchParams, RegisterParams};
use crate::pipeline::tail;

/// The stages of one registration, in the order they run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum StageName {
    /// Depth frames rendered for point-cloud-only scans (`virtual-frames`).
    VirtualFrames,
    /// Keypoints and geometric features of both scans (`geo-fpfh`, or learned features).
    Geo,
    DepthVideo,
    Generation,
    /// In memory.
    ViewSelect,
    Lift,
    /// Per-image VFM descriptors of the selected views at their lifted pixels (`vfm-view`).
    Vfm,
    /// Per-keypoint image descriptors of a per-image VFM (`image-points`).
    ImagePoints,
    /// Per-keypoint descriptors of a pair-conditioned VFM (`image-points-pair`).
    PairVfm,
    /// Similarity, calibration, fusion, selection, estimation, metrics (in memory).
    Fusion,
}

impl StageName {
    pub const ALL: [StageName; 10] = [
        StageName::VirtualFrames,
        StageName::Geo,
        StageName::DepthVideo,
        StageName::Generation,
        StageName::ViewSelect,
        StageName::Lift,
        StageName::Vfm,
        StageName::ImagePoints,
        StageName::PairVfm,
        StageName::Fusion,
    ];

    /// The stage's name as its key carries it (the cache folder of a cached stage).
    pub fn key_name(self) -> &'static str {
        match self {
            StageName::VirtualFrames => virtual_frames::STAGE,
            StageName::Geo => geo::STAGE,
            StageName::DepthVideo => depth_video::STAGE,
            StageName::Generation => generation::STAGE,
            StageName::ViewSelect => view_select::STAGE,
            StageName::Vfm => vfm::STAGE,
            StageName::Lift => lift::STAGE,
            StageName::ImagePoints => image_points::STAGE,
            StageName::PairVfm => pair_vfm::STAGE,
            StageName::Fusion => tail::STAGE,
        }
    }

    /// For people (the stage panel).
    pub fn label(self) -> &'static str {
        match self {
            StageName::VirtualFrames => "virtual frames",
            StageName::Geo => "geometric features",
            StageName::DepthVideo => "depth video",
            StageName::Generation => "generation",
            StageName::ViewSelect => "view selection",
            StageName::Vfm => "VFM views",
            StageName::Lift => "lift",
            StageName::ImagePoints => "image point features",
            StageName::PairVfm => "pair VFM point features",
            StageName::Fusion => "similarity, fusion and estimation",
        }
    }
}

/// Every stage's key hashes for one pair and parameter set (several for per-scan and
/// per-view stages), in run order. `None`: not known before an earlier stage runs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StageKeys {
    stages: Vec<(StageName, Option<Vec<String>>)>,
    /// The fusion key's input hashes (None: not known before an earlier stage runs).
    fusion_inputs: Option<Vec<String>>,
    /// The parameters the keys before fusion were computed from (see [`upstream_params`]).
    upstream: Option<RegisterParams>,
}

impl StageKeys {
    /// The keys of `pair`'s stages under `params`; `cache` is read for the stage outputs that
    /// later keys depend on (see the module doc). Errors are those the run would report
    /// first (too few frames, a bad K or m, a missing model file, an unreadable depth file).
    pub fn compute(
        pair: &ScanPair,
        params: &RegisterParams,
        cache: Option<&Cache>,
        memo: &Memo,
    ) -> Result<StageKeys> {
        let mut k = StageKeys {
            upstream: Some(upstream_params(params)),
            ..StageKeys::default()
        };
        let geo = geo_keys(pair, params, memo)?;
        k.fusion_inputs = match &params.image {
            None => {
                k.set(StageName::Geo, Some(geo.clone()));
                Some(geo[..2].to_vec())
            }
            Some(ib) => image_keys(&mut k, pair, params, ib, (cache, memo), &geo)?
                .map(|i| vec![geo[0].clone(), geo[1].clone(), i]),
        };
        k.set_fusion(params)?;
        k.stages.sort_by_key(|(s, _)| *s);
        Ok(k)
    }

    /// The keys under `params`, from these when `params` differs from theirs only in what the
    /// fusion stage alone reads (fusion, estimator, inlier threshold): then only the fusion key
    /// is formed again, without hashing a cloud or a frame. Otherwise [`Self::compute`]. A
    /// file changed on disk since is not noticed on the first path; the inspector's worker
    /// re-fuses its in-memory inputs then anyway.
    pub fn refreshed(
        &self,
        pair: &ScanPair,
        params: &RegisterParams,
        cache: Option<&Cache>,
        memo: &Memo,
    ) -> Result<StageKeys> {
        if self.upstream.as_ref() != Some(&upstream_params(params)) {
            return StageKeys::compute(pair, params, cache, memo);
        }
        let mut k = self.clone();
        k.set_fusion(params)?;
        k.stages.sort_by_key(|(s, _)| *s);
        Ok(k)
    }

    fn set_fusion(&mut self, params: &RegisterParams) -> Result<()> {
        let fusion = match &self.fusion_inputs {
            Some(inputs) => {
                let inputs: Vec<&str> = inputs.iter().map(String::as_str).collect();
                Some(vec![tail::key(params, &inputs)?.hash])
            }
            None => None,
        };
        self.set(StageName::Fusion, fusion);
        Ok(())
    }

    /// The key hashes of `stage`: None when the stage is not part of this registration or its
    /// key is not known yet (see [`Self::is_known`]).
    pub fn get(&self, stage: StageName) -> Option<&[String]> {
        self.stages
            .iter()
            .find(|(s, _)| *s == stage)
            .and_then(|(_, k)| k.as_deref())
    }

    /// Whether `stage` is part of this registration and its key is known.
    pub fn is_known(&self, stage: StageName) -> bool {
        self.get(stage).is_some()
    }

    /// The stages of this registration, in run order.
    pub fn stages(&self) -> impl Iterator<Item = StageName> + '_ {
        self.stages.iter().map(|(s, _)| *s)
    }

    /// The stages of `new` that must run again after `self`: their key differs, they were not
    /// part of `self`, or their key is not known before an earlier stage runs. Earliest first.
    pub fn invalidated_by(&self, new: &StageKeys) -> Vec<StageName> {
        new.stages
            .iter()
            .filter(|(s, k)| k.is_none() || self.get(*s) != k.as_deref())
            .map(|(s, _)| *s)
            .collect()
    }

    fn set(&mut self, stage: StageName, keys: Option<Vec<String>>) {
        self.stages.retain(|(s, _)| *s != stage);
        self.stages.push((stage, keys));
    }

    /// Marks every image-branch stage from `from` on (those this VFM runs) as not known.
    fn unknown_from(&mut self, from: StageName, ib: &ImageBranchParams) {
        let pair_model = vfm::is_pair_conditioned(&ib.vfm);
        for s in StageName::ALL {
            let applies = match s {
                StageName::VirtualFrames | StageName::Geo | StageName::Fusion => false,
                StageName::Vfm | StageName::ImagePoints => !pair_model,
                StageName::PairVfm => pair_model,
                _ => true,
            };
            if applies && s >= from {
                self.set(s, None);
            }
        }
    }
}

/// `params` without what only the fusion stage's key reads ([`tail::key`]: fusion, estimator,
/// inlier threshold): two parameter sets equal in it give the same keys before fusion.
fn upstream_params(params: &RegisterParams) -> RegisterParams {
    RegisterParams {
        fusion: Default::default(),
        estimator: Default::default(),
        inlier_threshold: crate::estimate::scale::Scaled::Set(0.0),
        success: Default::default(),
        ..params.clone()
    }
}

/// The stages `new` re-runs after a registration of `pair` under `old`, earliest first (an
/// empty list: nothing to re-run). See [`StageKeys`].
pub fn invalidated(
    pair: &ScanPair,
    old: &RegisterParams,
    new: &RegisterParams,
    cache: Option<&Cache>,
    memo: &Memo,
) -> Result<Vec<StageName>> {
    let a = StageKeys::compute(pair, old, cache, memo)?;
    let b = StageKeys::compute(pair, new, cache, memo)?;
    Ok(a.invalidated_by(&b))
}

/// Both scans' geometric-branch keys: the `geo-fpfh` key for FPFH, the `geo-spinnet` key for
/// SpinNet (hashing the export through `memo`); learned features are read from their files on
/// every run (not cached), keyed here by the source and the voxel.
fn geo_keys(pair: &ScanPair, params: &RegisterParams, memo: &Memo) -> Result<Vec<String>> {
    if let Some(input) = crate::pipeline::geo::spinnet_input(params) {
        let id = super::geo_spinnet::model_id(memo, &input)?;
        return Ok(vec![
            super::geo_spinnet::key(&pair.source, &input, &id)?.hash,
            super::geo_spinnet::key(&pair.target, &input, &id)?.hash,
        ]);
    }
    match &params.geo_features {
        GeoFeatureSource::Fpfh => Ok(vec![
            geo::key(&pair.source, params.voxel)?.hash,
            geo::key(&pair.target, params.voxel)?.hash,
        ]),
        other => {
            let k = CacheKey::new(
                "geo-learned",
                1,
                &[],
                &serde_json::json!({ "features": other, "voxel": params.voxel }),
            )?;
            Ok(vec![k.hash.clone(), k.hash])
        }
    }
}

/// The image branch's keys into `k`; returns the key of the image descriptors the fusion
/// reads (None when not known yet).
fn image_keys(
    k: &mut StageKeys,
    pair: &ScanPair,
    params: &RegisterParams,
    ib: &ImageBranchParams,
    (cache, memo): (Option<&Cache>, &Memo),
    geo: &[String],
) -> Result<Option<String>> {
    k.set(StageName::Geo, Some(geo.to_vec()));
    // Point-cloud-only scans: the depth frames come from the virtual camera.
    let owned;
    let pair = if pair.source.frames.is_some() && pair.target.frames.is_some() {
        pair
    } else {
        let bare: Vec<&Scan> = [&pair.source, &pair.target]
            .into_iter()
            .filter(|s| s.frames.is_none())
            .collect();
        let mut keys = Vec::new();
        for s in bare {
            let cam = ib.virtual_camera.resolve(&s.cloud);
            keys.extend(virtual_frames::keys(
                s,
                ib.frames_per_fragment,
                cam,
                ib.lidar_cameras,
                ib.lidar_origin,
            )?);
        }
        k.set(
            StageName::VirtualFrames,
            Some(keys.iter().map(|k| k.hash.clone()).collect()),
        );
        let cached = |c: &Cache| keys.iter().all(|k| matches!(c.get(k), Ok(Some(_))));
        match cache {
            Some(c) if cached(c) => {
                // All hits: nothing is rendered.
                owned = with_virtual_frames(&mut FrameStore::new(Some(c)), pair, ib)?.0;
                &owned
            }
            _ => {
                k.unknown_from(StageName::DepthVideo, ib);
                return Ok(None);
            }
        }
    };
    let l = ib.frames_per_fragment;
    let (src_fs, tgt_fs) = (frames_of(&pair.source, l)?, frames_of(&pair.target, l)?);
    let planned = view_select::planned(ib)?;
    let vfm_id = vfm::vfm_id(memo, &ib.vfm)?;
    let video = depth_video::plan(memo, src_fs, tgt_fs, l)?;
    k.set(StageName::DepthVideo, Some(vec![video.key.hash.clone()]));
    let Some(video_hash) = cache.and_then(|c| depth_video::cached_hash(c, &video.key)) else {
        k.unknown_from(StageName::Generation, ib);
        return Ok(None);
    };
    let lidar = video.lidar();
    let gen = generation::plan(memo, pair, ib, (&video_hash, lidar), src_fs, tgt_fs, l)?.key;
    k.set(StageName::Generation, Some(vec![gen.hash.clone()]));
    let Some(meta) = cache.and_then(|c| generation::cached_meta(c, &gen)) else {
        k.unknown_from(StageName::ViewSelect, ib);
        return Ok(None);
    };
    let sel = view_select::select(planned, meta.frames, ib)?;
    k.set(
        StageName::ViewSelect,
        Some(vec![view_select::key(ib, meta.frames)?.hash]),
    );
    let lift_key = |scan: &Scan, fs: &FrameSet, depth_idx: &[usize]| -> Result<CacheKey> {
        let geo_key = geo::key(scan, params.voxel)?;
        let inp = LiftInput {
            geo_key: &geo_key,
            keypoints: &[],
            frames: fs,
            depth_idx,
        };
        lift::key_for(
            memo,
            &inp,
            ib.lift_radius_at(params.voxel),
            (meta.width, meta.height),
        )
    };
    let src_lift = lift_key(&pair.source, src_fs, &sel.src_depth)?;
    let tgt_lift = lift_key(&pair.target, tgt_fs, &sel.tgt_depth)?;
    k.set(
        StageName::Lift,
        Some(vec![src_lift.hash.clone(), tgt_lift.hash.clone()]),
    );
    let lifts = (&src_lift, &tgt_lift);
    if vfm::is_pair_conditioned(&ib.vfm) {
        let key = pair_vfm::key(lifts, &gen, &vfm_id, &sel)?;
        k.set(StageName::PairVfm, Some(vec![key.hash.clone()]));
        return Ok(Some(key.hash));
    }
    let views = |idx: &[usize], lift: &CacheKey| -> Result<Vec<String>> {
        idx.iter()
            .enumerate()
            .map(|(v, &g)| vfm::key(&gen, lift, (g, v), &vfm_id, vfm::cell_of(ib)).map(|k| k.hash))
            .collect()
    };
    let (src_views, tgt_views) = (
        views(&sel.src_generated, &src_lift)?,
        views(&sel.tgt_generated, &tgt_lift)?,
    );
    k.set(
        StageName::Vfm,
        Some(src_views.iter().chain(&tgt_views).cloned().collect()),
    );
    let key = image_points::key(lifts, (&src_views, &tgt_views))?;
    k.set(StageName::ImagePoints, Some(vec![key.hash.clone()]));
    Ok(Some(key.hash))
}

#[cfg(test)]
mod tests {
    use super::StageName::*;
    use super::*;
    use crate::fusion::Calibration;
    use crate::pipeline::params::WfmSpec;
    use crate::pipeline::stages::Ctx;

    fn demo_pair() -> ScanPair {
        let manifest =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml");
        let ds = crate::dataset::Dataset::load(&manifest).unwrap();
        let id = ds.pairs()[0].id.clone();
        ds.load_pair(&id).unwrap()
    }

    /// The demo's image-branch parameters (as `tests/common::demo_params`): L = 8, m = 1, K = 2.
    fn demo_params() -> RegisterParams {
        RegisterParams {
            voxel: 0.05,
            image: Some(ImageBranchParams {
                backend: WfmSpec::Builtin,
                frames_per_fragment: 8,
                margin: 1,
                k: 2,
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    /// Runs the depth video and the generation of `params` into `cache` (what a registration
    /// leaves there before its views are described).
    fn generate(pair: &ScanPair, params: &RegisterParams, cache: &Cache) {
        let ib = params.image.as_ref().unwrap();
        let l = ib.frames_per_fragment;
        let memo = Memo::default();
        let mut ctx = Ctx::new(Some(cache), &memo);
        let (s, t) = (
            frames_of(&pair.source, l).unwrap(),
            frames_of(&pair.target, l).unwrap(),
        );
        let mut video = depth_video::run(&mut ctx, pair, s, t, l).unwrap();
        generation::run(&mut ctx, pair, ib, &mut video, s, t, l, true).unwrap();
    }

    #[test]
    fn a_change_invalidates_exactly_the_stages_whose_keys_differ() {
        let pair = demo_pair();
        let memo = Memo::default();
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        let old = demo_params();
        generate(&pair, &old, &cache);
        let keys = StageKeys::compute(&pair, &old, Some(&cache), &Memo::default()).unwrap();
        assert_eq!(
            keys.stages().collect::<Vec<_>>(),
            [
                Geo,
                DepthVideo,
                Generation,
                ViewSelect,
                Lift,
                Vfm,
                ImagePoints,
                Fusion
            ]
        );
        assert!(keys.stages().all(|s| keys.is_known(s)));
        // The keys are the ones the stages stored under.
        for s in [DepthVideo, Generation] {
            let k = &keys.get(s).unwrap()[0];
            assert!(dir.path().join(s.key_name()).join(k).is_dir(), "{s:?}");
        }
        assert_eq!(keys.get(Vfm).unwrap().len(), 4);
        let inv =
            |new: &RegisterParams| invalidated(&pair, &old, new, Some(&cache), &memo).unwrap();
        assert_eq!(inv(&old), []);

        // The image temperature: only the in-memory tail.
        let mut p = old.clone();
        p.fusion.calibration_img = Calibration::RowSoftmax { tau: 0.05 };
        assert_eq!(inv(&p), [Fusion]);
        // The estimator's threshold too.
        let mut p = old.clone();
        p.inlier_threshold = crate::estimate::scale::Scaled::Set(0.2);
        assert_eq!(inv(&p), [Fusion]);

        // K: view selection and everything after it; the depth video and generation stay.
        let mut p = old.clone();
        p.image.as_mut().unwrap().k = 3;
        assert_eq!(inv(&p), [ViewSelect, Lift, Vfm, ImagePoints, Fusion]);

        // The prompt: a new generation, so nothing after it is known before it runs.
        let mut p = old.clone();
        p.image.as_mut().unwrap().prompt.scene = "a different room".into();
        assert_eq!(
            inv(&p),
            [Generation, ViewSelect, Lift, Vfm, ImagePoints, Fusion]
        );
        // Once generated, the lift is found to be unchanged (same frame size, same views).
        generate(&pair, &p, &cache);
        assert_eq!(inv(&p), [Generation, Vfm, ImagePoints, Fusion]);

        // The FPFH voxel: the geometric branch, the lift of its keypoints, the views
        // described at the lifted pixels, the point features and the tail; the depth video
        // and the generation stay.
        let mut p = old.clone();
        p.voxel = 0.04;
        assert_eq!(inv(&p), [Geo, Lift, Vfm, ImagePoints, Fusion]);

        // The lift radius: the lift onward.
        let mut p = old.clone();
        p.image.as_mut().unwrap().lift_radius = crate::estimate::scale::Scaled::Set(0.1);
        assert_eq!(inv(&p), [Lift, Vfm, ImagePoints, Fusion]);

        // Without a cache the generation's input is not known before the depth video runs.
        let none = invalidated(&pair, &old, &old, None, &memo).unwrap();
        assert_eq!(
            none,
            [Generation, ViewSelect, Lift, Vfm, ImagePoints, Fusion]
        );
    }

    /// `refreshed` gives exactly `compute`'s keys: from the kept keys for fusion-only changes,
    /// by computing for any other.
    #[test]
    fn refreshed_keys_equal_computed_keys() {
        let pair = demo_pair();
        let memo = Memo::default();
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        let old = demo_params();
        generate(&pair, &old, &cache);
        let kept = StageKeys::compute(&pair, &old, Some(&cache), &memo).unwrap();
        let mut changes: Vec<RegisterParams> = Vec::new();
        let mut p = old.clone();
        p.fusion.calibration_img = Calibration::RowSoftmax { tau: 0.05 };
        changes.push(p);
        let mut p = old.clone();
        p.fusion.mode = crate::fusion::FusionMode::NoisyOr;
        p.inlier_threshold = crate::estimate::scale::Scaled::Set(0.2);
        changes.push(p);
        let mut p = old.clone();
        p.estimator = crate::estimate::EstimatorKind::WeightedSvd;
        changes.push(p);
        let mut p = old.clone();
        p.voxel = 0.04;
        changes.push(p);
        let mut p = old.clone();
        p.image.as_mut().unwrap().k = 3;
        changes.push(p);
        changes.push(RegisterParams {
            image: None,
            ..old.clone()
        });
        for (i, p) in changes.iter().enumerate() {
            let computed = StageKeys::compute(&pair, p, Some(&cache), &memo).unwrap();
            let refreshed = kept.refreshed(&pair, p, Some(&cache), &memo).unwrap();
            assert_eq!(refreshed, computed, "change {i}");
            assert!(!kept.invalidated_by(&refreshed).is_empty(), "change {i}");
        }
        // Geometry only as well.
        let geo = RegisterParams {
            image: None,
            ..old.clone()
        };
        let kept = StageKeys::compute(&pair, &geo, None, &memo).unwrap();
        let mut p = geo.clone();
        p.fusion.calibration_geo = Calibration::RowSoftmax { tau: 0.3 };
        let computed = StageKeys::compute(&pair, &p, None, &memo).unwrap();
        assert_eq!(kept.refreshed(&pair, &p, None, &memo).unwrap(), computed);
        assert_eq!(kept.invalidated_by(&computed), [Fusion]);
    }

    #[test]
    fn geometry_only_and_switching_the_image_branch() {
        let pair = demo_pair();
        let memo = Memo::default();
        let geo_only = RegisterParams {
            image: None,
            ..demo_params()
        };
        let keys = StageKeys::compute(&pair, &geo_only, None, &Memo::default()).unwrap();
        assert_eq!(keys.stages().collect::<Vec<_>>(), [Geo, Fusion]);
        let mut p = geo_only.clone();
        p.voxel = 0.04;
        assert_eq!(
            invalidated(&pair, &geo_only, &p, None, &memo).unwrap(),
            [Geo, Fusion]
        );
        let mut p = geo_only.clone();
        p.fusion.calibration_geo = Calibration::RowSoftmax { tau: 0.2 };
        assert_eq!(
            invalidated(&pair, &geo_only, &p, None, &memo).unwrap(),
            [Fusion]
        );
        // Turning the image branch on runs its stages (the geometric keys are the same).
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        generate(&pair, &demo_params(), &cache);
        assert_eq!(
            invalidated(&pair, &geo_only, &demo_params(), Some(&cache), &memo).unwrap(),
            [
                DepthVideo,
                Generation,
                ViewSelect,
                Lift,
                Vfm,
                ImagePoints,
                Fusion
            ]
        );
        // A bad K is the error the run would give.
        let mut p = demo_params();
        p.image.as_mut().unwrap().k = 9;
        assert!(StageKeys::compute(&pair, &p, Some(&cache), &Memo::default()).is_err());
    }
}
