//! The stage graph of one registration, declared once: [`plan`] gives the ordered steps of a
//! pair under a parameter set, each with its key when it is known before anything runs;
//! [`super::Registration::run`] executes the steps in that order and fills every key as
//! its step runs (the result carries the filled plan, [`RegistrationResult::plan`]); and
//! [`Plan::invalidated_by`] compares two plans: the stages a settings change must run again.
//!
//! Which stages a registration has is decided in one place, [`Plan::skeleton`]: the geometric
//! branch and the in-memory tail always; with the image branch, the virtual frames (scans
//! without sensor frames), the depth video, the generation, the view selection, the lifts, then
//! the per-image VFM's views and point features or the pair VFM's point features.
//!
//! Some keys read an earlier stage's *output*: a world model's generation is keyed by the depth
//! video's content hash, the view selection by the generated video's length, the lift by the
//! generated frames' size, and for point-cloud-only scans everything after the virtual frames
//! by the rendered depth files. A frame-by-frame backend (the built-in shading, the oracle) has
//! no depth video: its views' keys read their own depth (colour) files, its video is 2L frames,
//! and the built-in shading fixes its frame size, so with it every key is known before a run. [`plan`] reads these from the cache; when the producing stage's entry
//! is not there (a new prompt, no cache), the keys after it are filled as the steps run, and a
//! comparison counts those stages as invalidated.
//!
//! [`RegistrationResult::plan`]: super::RegistrationResult::plan

pub use super::graph::{Plan, StageName, Step};

use super::memo::Memo;
use super::params::{GeoFeatureSource, ImageBranchParams, RegisterParams};
use super::stages::depth_video::{self, frames_of};
use super::stages::lift::LiftInput;
use super::stages::virtual_frames::{self, with_virtual_frames, FrameStore};
use super::stages::{generation, geo, image_points, lift, pair_vfm, vfm, view_select};
use super::tail;
use crate::cache::{Cache, CacheKey};
use crate::dataset::{FrameSet, Scan, ScanPair};
use crate::error::Result;

/// The plan of `pair` under `params`: every step with its key where it is known now; `cache`
/// is read for the stage outputs that later keys depend on (see the module doc). Hashes input
/// files (clouds, depth frames, the model file) and computes no stage. Errors are those the
/// run would report first (too few frames, a bad K or m, a missing model file, an unreadable
/// depth file).
pub fn plan(
    pair: &ScanPair,
    params: &RegisterParams,
    cache: Option<&Cache>,
    memo: &Memo,
) -> Result<Plan> {
    let mut p = Plan::skeleton(pair, params);
    let geo = geo_keys(pair, params, memo)?;
    p.set(StageName::Geo, geo);
    if let Some(ib) = &params.image {
        image_keys(&mut p, pair, params, ib, (cache, memo))?;
    }
    p.fill_fusion()?;
    Ok(p)
}

/// The stages `new` re-runs after a registration of `pair` under `old`, earliest first (an
/// empty list: nothing to re-run). See [`Plan::invalidated_by`].
pub fn invalidated(
    pair: &ScanPair,
    old: &RegisterParams,
    new: &RegisterParams,
    cache: Option<&Cache>,
    memo: &Memo,
) -> Result<Vec<StageName>> {
    let a = plan(pair, old, cache, memo)?;
    let b = plan(pair, new, cache, memo)?;
    Ok(a.invalidated_by(&b))
}

impl Plan {
    /// The plan under `params`, from this one when `params` differs from its parameters only
    /// in what the fusion stage alone reads (fusion, estimator, inlier threshold): then only
    /// the fusion key is formed again, without hashing a cloud or a frame. Otherwise
    /// [`plan`]. A file changed on disk since is not noticed on the first path; the
    /// inspector's worker re-fuses its in-memory inputs then anyway.
    pub fn replan(
        &self,
        pair: &ScanPair,
        params: &RegisterParams,
        cache: Option<&Cache>,
        memo: &Memo,
    ) -> Result<Plan> {
        if upstream_params(&self.params) != upstream_params(params) {
            return plan(pair, params, cache, memo);
        }
        let mut p = self.clone();
        p.params = params.clone();
        p.ran = 0;
        p.fill_fusion()?;
        Ok(p)
    }

    /// The fusion step's key from both scans' geometric keys and the image descriptors' key
    /// (left unknown while one of them is).
    pub(crate) fn fill_fusion(&mut self) -> Result<()> {
        let geo = self.get(StageName::Geo).map(|g| g[..2].to_vec());
        let image = match &self.params.image {
            None => Some(None),
            Some(ib) => {
                let stage = match vfm::is_pair_conditioned(&ib.vfm) {
                    true => StageName::PairVfm,
                    false => StageName::ImagePoints,
                };
                self.get(stage).map(|k| Some(k[0].clone()))
            }
        };
        let key = match (geo, image) {
            (Some(mut inputs), Some(image)) => {
                inputs.extend(image);
                let inputs: Vec<&str> = inputs.iter().map(String::as_str).collect();
                Some(tail::key(&self.params, &inputs)?.hash)
            }
            _ => None,
        };
        if let Some(s) = self.steps.iter_mut().find(|s| s.stage == StageName::Fusion) {
            s.keys = key.map(|k| vec![k]);
        }
        Ok(())
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

/// The key of learned features read from files (not cached: read on every run), by their
/// source and the voxel, for both scans.
pub(crate) fn learned_geo_keys(params: &RegisterParams) -> Result<Vec<String>> {
    let RegisterParams {
        voxel,
        geo_features,
        fusion: _,
        estimator: _,
        inlier_threshold: _,
        image: _,
        success: _,
        // each scale hypothesis is a registration at one voxel
        scales: _,
    } = params;
    let k = CacheKey::new(
        "geo-learned",
        1,
        &[],
        &serde_json::json!({ "features": geo_features, "voxel": voxel }),
    )?;
    Ok(vec![k.hash.clone(), k.hash])
}

/// Both scans' geometric-branch keys: the `geo-fpfh` key for FPFH, the `geo-spinnet` key for
/// SpinNet (hashing the export through `memo`), [`learned_geo_keys`] for learned features.
fn geo_keys(pair: &ScanPair, params: &RegisterParams, memo: &Memo) -> Result<Vec<String>> {
    if let Some(input) = super::geo::spinnet_input(params) {
        let id = super::stages::geo_spinnet::model_id(memo, &input)?;
        return Ok(vec![
            super::stages::geo_spinnet::key(&pair.source, &input, &id)?.hash,
            super::stages::geo_spinnet::key(&pair.target, &input, &id)?.hash,
        ]);
    }
    match &params.geo_features {
        GeoFeatureSource::Fpfh => Ok(vec![
            geo::key(&pair.source, geo::settings(params))?.hash,
            geo::key(&pair.target, geo::settings(params))?.hash,
        ]),
        _ => learned_geo_keys(params),
    }
}

/// The image branch's keys into `p`, as far as they are known before anything runs.
fn image_keys(
    p: &mut Plan,
    pair: &ScanPair,
    params: &RegisterParams,
    ib: &ImageBranchParams,
    (cache, memo): (Option<&Cache>, &Memo),
) -> Result<()> {
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
            let (l, camera, cameras, origin) = virtual_frames::settings(ib, s);
            keys.extend(virtual_frames::keys(s, l, camera, cameras, origin)?);
        }
        p.set(
            StageName::VirtualFrames,
            keys.iter().map(|k| k.hash.clone()).collect(),
        );
        let cached = |c: &Cache| keys.iter().all(|k| matches!(c.get(k), Ok(Some(_))));
        match cache {
            Some(c) if cached(c) => {
                // All hits: nothing is rendered.
                owned = with_virtual_frames(&mut FrameStore::new(Some(c)), pair, ib)?.0;
                &owned
            }
            _ => return Ok(()),
        }
    };
    let l = depth_video::settings(ib);
    let (src_fs, tgt_fs) = (frames_of(&pair.source, l)?, frames_of(&pair.target, l)?);
    let planned = view_select::planned(ib)?;
    let vfm_id = vfm::vfm_id(memo, &ib.vfm)?;
    // Each side's generation key (the same for both when the whole video is one entry), the
    // key a pair VFM reads, and the video's length and frame size.
    let (gens, pair_gen, (n_frames, width, height)) = if generation::frame_by_frame(&ib.backend) {
        let v = generation::plan_views(memo, pair, ib, (src_fs, tgt_fs), &planned, l)?;
        p.set(
            StageName::Generation,
            v.keys.iter().map(|k| k.hash.clone()).collect(),
        );
        // The built-in shading fixes its frame size; the oracle's frames say theirs.
        let size = match (v.backend.frame_size(), cache) {
            (Some(s), _) => s,
            (None, Some(c)) => match generation::cached_meta(c, &v.keys[0]) {
                Some(m) => (m.width, m.height),
                None => return Ok(()),
            },
            (None, None) => return Ok(()),
        };
        let pair_gen = generation::pair_key([&v.keys[0], &v.keys[1]])?;
        let [a, b] = v.keys;
        ([a, b], pair_gen, (2 * l, size.0, size.1))
    } else {
        let video = depth_video::plan(memo, src_fs, tgt_fs, l)?;
        p.set(StageName::DepthVideo, vec![video.key.hash.clone()]);
        let Some(video_hash) = cache.and_then(|c| depth_video::cached_hash(c, &video.key)) else {
            return Ok(());
        };
        let lidar = video.lidar();
        let gen = generation::plan(memo, pair, ib, (&video_hash, lidar), src_fs, tgt_fs, l)?.key;
        p.set(StageName::Generation, vec![gen.hash.clone()]);
        let Some(meta) = cache.and_then(|c| generation::cached_meta(c, &gen)) else {
            return Ok(());
        };
        let size = (meta.frames, meta.width, meta.height);
        ([gen.clone(), gen.clone()], gen, size)
    };
    let sel = view_select::select(planned, n_frames, ib)?;
    p.set(
        StageName::ViewSelect,
        vec![view_select::key(ib, n_frames)?.hash],
    );
    let lift_key = |scan: &Scan, fs: &FrameSet, depth_idx: &[usize]| -> Result<CacheKey> {
        let geo_key = geo::key(scan, geo::settings(params))?;
        let inp = LiftInput {
            geo_key: &geo_key,
            keypoints: &[],
            frames: fs,
            depth_idx,
        };
        lift::key_for(memo, &inp, lift::settings(params), (width, height))
    };
    let src_lift = lift_key(&pair.source, src_fs, &sel.src_depth)?;
    let tgt_lift = lift_key(&pair.target, tgt_fs, &sel.tgt_depth)?;
    p.set(
        StageName::Lift,
        vec![src_lift.hash.clone(), tgt_lift.hash.clone()],
    );
    let lifts = (&src_lift, &tgt_lift);
    if vfm::is_pair_conditioned(&ib.vfm) {
        let key = pair_vfm::key(lifts, &pair_gen, &vfm_id, &sel)?;
        p.set(StageName::PairVfm, vec![key.hash]);
        return Ok(());
    }
    let (_, cell) = vfm::settings(ib);
    let views = |gen: &CacheKey, idx: &[usize], lift: &CacheKey| -> Result<Vec<String>> {
        idx.iter()
            .enumerate()
            .map(|(v, &g)| vfm::key(gen, lift, (g, v), &vfm_id, cell).map(|k| k.hash))
            .collect()
    };
    let (src_views, tgt_views) = (
        views(&gens[0], &sel.src_generated, &src_lift)?,
        views(&gens[1], &sel.tgt_generated, &tgt_lift)?,
    );
    p.set(
        StageName::Vfm,
        src_views.iter().chain(&tgt_views).cloned().collect(),
    );
    let key = image_points::key(lifts, (&src_views, &tgt_views))?;
    p.set(StageName::ImagePoints, vec![key.hash]);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::StageName::*;
    use super::*;
    use crate::fusion::Calibration;
    use crate::pipeline::params::WfmSpec;
    use crate::pipeline::stages::Ctx;
    use crate::pipeline::Registration;

    fn demo_pair() -> ScanPair {
        let manifest =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml");
        let ds = crate::dataset::Dataset::load(&manifest).unwrap();
        let id = ds.pairs()[0].id.clone();
        ds.load_pair(&id).unwrap()
    }

    /// The demo's image-branch parameters (as `tests/common::demo_params`): L = 8, m = 1, K = 2,
    /// keypoints on a 10 cm grid (the plan does not depend on their number; the runs' cost does).
    fn demo_params() -> RegisterParams {
        RegisterParams {
            voxel: 0.1,
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
    /// leaves there before its views are described): a frame-by-frame backend's selected views.
    fn generate(pair: &ScanPair, params: &RegisterParams, cache: &Cache) {
        let ib = params.image.as_ref().unwrap();
        let l = ib.frames_per_fragment;
        let memo = Memo::default();
        let mut ctx = Ctx::new(Some(cache), &memo);
        let (s, t) = (
            frames_of(&pair.source, l).unwrap(),
            frames_of(&pair.target, l).unwrap(),
        );
        if generation::frame_by_frame(&ib.backend) {
            let sel = view_select::planned(ib).unwrap();
            generation::run_views(&mut ctx, pair, ib, (s, t), &sel, true).unwrap();
        } else {
            let mut video = depth_video::run(&mut ctx, pair, s, t, l).unwrap();
            generation::run(&mut ctx, pair, ib, &mut video, s, t, l, true).unwrap();
        }
    }

    #[test]
    fn a_change_invalidates_exactly_the_stages_whose_keys_differ() {
        let pair = demo_pair();
        let memo = Memo::default();
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        let old = demo_params();
        generate(&pair, &old, &cache);
        let keys = plan(&pair, &old, Some(&cache), &Memo::default()).unwrap();
        assert_eq!(
            keys.stages().collect::<Vec<_>>(),
            [Geo, Generation, ViewSelect, Lift, Vfm, ImagePoints, Fusion]
        );
        assert!(keys.stages().all(|s| keys.is_known(s)));
        // The keys are the ones the stage stored under: the built-in generator draws each
        // side's selected views into an entry of its own (no depth video).
        assert_eq!(keys.get(Generation).unwrap().len(), 2);
        for k in keys.get(Generation).unwrap() {
            assert!(dir.path().join(Generation.key_name()).join(k).is_dir());
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
        p.inlier_threshold = crate::estimate::scale::Scaled::Set(0.3);
        assert_eq!(inv(&p), [Fusion]);

        // K: other views drawn (only the selected ones are), and everything after.
        let mut p = old.clone();
        p.image.as_mut().unwrap().k = 3;
        assert_eq!(
            inv(&p),
            [Generation, ViewSelect, Lift, Vfm, ImagePoints, Fusion]
        );

        // The prompt: a new generation; the built-in generator's frame size is fixed, so the
        // lift is known to be unchanged (same frame size, same views) before it runs.
        let mut p = old.clone();
        p.image.as_mut().unwrap().prompt.scene = "a different room".into();
        assert_eq!(inv(&p), [Generation, Vfm, ImagePoints, Fusion]);
        generate(&pair, &p, &cache);
        assert_eq!(inv(&p), [Generation, Vfm, ImagePoints, Fusion]);

        // The FPFH voxel: the geometric branch, the lift of its keypoints, the views
        // described at the lifted pixels, the point features and the tail; the depth video
        // and the generation stay.
        let mut p = old.clone();
        p.voxel = 0.12;
        assert_eq!(inv(&p), [Geo, Lift, Vfm, ImagePoints, Fusion]);

        // The VFM: its views and the point features (the lift keeps its pixels); the cell
        // size only for a dense model; a pair model replaces both with its own step.
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut p = old.clone();
        p.image.as_mut().unwrap().vfm = crate::vfm::VfmSpec::Alike {
            model: root.join("models/alike-t.onnx"),
        };
        assert_eq!(inv(&p), [Vfm, ImagePoints, Fusion]);
        let mut q = p.clone();
        q.image.as_mut().unwrap().dense_stride = 3;
        assert_eq!(
            invalidated(&pair, &p, &q, Some(&cache), &memo).unwrap(),
            [Vfm, ImagePoints, Fusion]
        );
        let mut q = old.clone();
        q.image.as_mut().unwrap().dense_stride = 3;
        assert_eq!(inv(&q), [], "XFeat does not read the cell size");
        let mut p = old.clone();
        p.image.as_mut().unwrap().vfm = crate::vfm::VfmSpec::Mast3r {
            model: root.join("tests/fixtures/tiny_mast3r.onnx"),
        };
        assert_eq!(inv(&p), [PairVfm, Fusion]);

        // The lift radius: the lift onward.
        let mut p = old.clone();
        p.image.as_mut().unwrap().lift_radius = crate::estimate::scale::Scaled::Set(0.15);
        assert_eq!(inv(&p), [Lift, Vfm, ImagePoints, Fusion]);

        // Without a cache too: the built-in generator's keys read only its views' depth files.
        let none = invalidated(&pair, &old, &old, None, &memo).unwrap();
        assert_eq!(none, []);
    }

    /// `replan` gives exactly `plan`'s keys: from the kept plan for fusion-only changes, by
    /// planning for any other.
    #[test]
    fn replanned_keys_equal_planned_keys() {
        let pair = demo_pair();
        let memo = Memo::default();
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        let old = demo_params();
        generate(&pair, &old, &cache);
        let kept = plan(&pair, &old, Some(&cache), &memo).unwrap();
        let mut changes: Vec<RegisterParams> = Vec::new();
        let mut p = old.clone();
        p.fusion.calibration_img = Calibration::RowSoftmax { tau: 0.05 };
        changes.push(p);
        let mut p = old.clone();
        p.fusion.mode = crate::fusion::FusionMode::NoisyOr;
        p.inlier_threshold = crate::estimate::scale::Scaled::Set(0.3);
        changes.push(p);
        let mut p = old.clone();
        p.estimator = crate::estimate::EstimatorKind::WeightedSvd;
        changes.push(p);
        let mut p = old.clone();
        p.voxel = 0.12;
        changes.push(p);
        let mut p = old.clone();
        p.image.as_mut().unwrap().k = 3;
        changes.push(p);
        changes.push(RegisterParams {
            image: None,
            ..old.clone()
        });
        for (i, p) in changes.iter().enumerate() {
            let computed = plan(&pair, p, Some(&cache), &memo).unwrap();
            let replanned = kept.replan(&pair, p, Some(&cache), &memo).unwrap();
            assert_eq!(replanned, computed, "change {i}");
            assert!(!kept.invalidated_by(&replanned).is_empty(), "change {i}");
        }
        // Geometry only as well.
        let geo = RegisterParams {
            image: None,
            ..old.clone()
        };
        let kept = plan(&pair, &geo, None, &memo).unwrap();
        let mut p = geo.clone();
        p.fusion.calibration_geo = Calibration::RowSoftmax { tau: 0.3 };
        let computed = plan(&pair, &p, None, &memo).unwrap();
        assert_eq!(kept.replan(&pair, &p, None, &memo).unwrap(), computed);
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
        let keys = plan(&pair, &geo_only, None, &Memo::default()).unwrap();
        assert_eq!(keys.stages().collect::<Vec<_>>(), [Geo, Fusion]);
        let mut p = geo_only.clone();
        p.voxel = 0.12;
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
            [Generation, ViewSelect, Lift, Vfm, ImagePoints, Fusion]
        );
        // A bad K is the error the run would give.
        let mut p = demo_params();
        p.image.as_mut().unwrap().k = 9;
        assert!(plan(&pair, &p, Some(&cache), &Memo::default()).is_err());
    }

    /// The stages of `p`, each once, in run order.
    fn stages_of(p: &Plan) -> Vec<StageName> {
        p.stages().collect()
    }

    fn assert_one_step_each(p: &Plan) {
        let s = stages_of(p);
        let mut sorted = s.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(s, sorted, "one step per stage, in run order");
    }

    /// A full plan holds exactly one step per stage that applies: an RGB-D pair with the image
    /// branch, a point-cloud-only pair (virtual frames first), geometry alone; a pair VFM
    /// swaps the views and point features for its own step. A run fills every key, and they
    /// are the keys the plan gives afterwards (the stages stored under them).
    #[test]
    fn a_full_plan_holds_one_step_per_applicable_stage() {
        let pair = demo_pair();
        let memo = Memo::default();
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        let p = demo_params();
        let rgbd = [Geo, Generation, ViewSelect, Lift, Vfm, ImagePoints, Fusion];
        let skeleton = Plan::skeleton(&pair, &p);
        assert_eq!(stages_of(&skeleton), rgbd);
        assert!(skeleton.steps().iter().all(|s| s.keys.is_none()));
        // Before anything ran: the built-in generator's keys read only the views' depth files
        // and its fixed frame size, so every key is known (a world model's generation waits
        // for the depth video's content hash, and the keys after it for its frames).
        let before = plan(&pair, &p, Some(&cache), &memo).unwrap();
        assert_eq!(stages_of(&before), rgbd);
        assert!(before.is_complete());

        // The run fills every key: the ones a plan made afterwards gives.
        let r = Registration::new(&p)
            .cache(&cache)
            .memo(&memo)
            .run(&pair)
            .unwrap();
        let ran = r.plan.as_ref().expect("the result carries its plan");
        assert_one_step_each(ran);
        assert!(ran.is_complete());
        assert_eq!(stages_of(ran), rgbd);
        let after = plan(&pair, &p, Some(&cache), &memo).unwrap();
        assert_eq!(ran, &after);
        assert_eq!(ran, &before);
        assert_eq!(ran.get(Vfm).unwrap().len(), 4);
        assert_eq!(ran.get(Geo).unwrap().len(), 2);
        assert_eq!(ran.get(Lift).unwrap().len(), 2);
        for s in [Geo, Generation, Lift, Vfm, ImagePoints] {
            for k in ran.get(s).unwrap() {
                assert!(dir.path().join(s.key_name()).join(k).is_dir(), "{s:?}");
            }
        }
        // Every timing is recorded under a stage of the plan.
        for t in &r.timings {
            let n = t.name.unwrap_or_else(|| panic!("{} has no stage", t.stage));
            assert!(ran.stages().any(|s| s == n), "{}: {n:?}", t.stage);
        }
        // A planned run checks its plan against its parameters.
        let ok = Registration::new(&p).cache(&cache).memo(&memo);
        assert_eq!(
            ok.run_plan(after.clone(), &pair).unwrap().plan.as_ref(),
            Some(ran)
        );
        let mut other = p.clone();
        other.voxel = 0.12;
        assert!(Registration::new(&other).run_plan(after, &pair).is_err());

        // A pair VFM: its point features instead of the views and per-image point features.
        let mut pm = p.clone();
        pm.image.as_mut().unwrap().vfm = crate::vfm::VfmSpec::Mast3r {
            model: "mast3r.onnx".into(),
        };
        let mut want = rgbd[..4].to_vec();
        want.extend([PairVfm, Fusion]);
        assert_eq!(stages_of(&Plan::skeleton(&pair, &pm)), want);

        // Geometry alone: the geometric branch and the tail, both known before the run.
        let geo = RegisterParams {
            image: None,
            ..p.clone()
        };
        let g = plan(&pair, &geo, None, &memo).unwrap();
        assert_eq!(stages_of(&g), [Geo, Fusion]);
        assert!(g.is_complete());
        let r = Registration::new(&geo).memo(&memo).run(&pair).unwrap();
        assert_eq!(r.plan.as_ref(), Some(&g));
        assert!(r.timings.iter().all(|t| t.name.is_some()));

        // A point-cloud-only pair: the virtual frames first; without a cache nothing after
        // them is known before they are rendered.
        let mut bare = pair.clone();
        bare.source.frames = None;
        bare.target.frames = None;
        let v = plan(&bare, &p, None, &memo).unwrap();
        let mut want = vec![VirtualFrames];
        want.extend(rgbd);
        assert_eq!(stages_of(&v), want);
        assert_one_step_each(&v);
        assert_eq!(
            v.get(VirtualFrames).unwrap().len(),
            2,
            "one pinhole entry per scan"
        );
        assert!(!v.is_known(Generation));
    }

    /// The built-in generator's views drawn one by one are the frames the whole video holds at
    /// those indices, bit for bit; each side's entry holds only its views.
    #[test]
    fn views_drawn_frame_by_frame_equal_the_whole_videos_frames() {
        let pair = demo_pair();
        let p = demo_params();
        let ib = p.image.as_ref().unwrap();
        let l = ib.frames_per_fragment;
        let memo = Memo::default();
        let mut ctx = Ctx::new(None, &memo);
        let (s, t) = (
            frames_of(&pair.source, l).unwrap(),
            frames_of(&pair.target, l).unwrap(),
        );
        let sel = view_select::planned(ib).unwrap();
        let views = generation::run_views(&mut ctx, &pair, ib, (s, t), &sel, true).unwrap();
        let mut video = depth_video::run(&mut ctx, &pair, s, t, l).unwrap();
        let (whole, _) = generation::run(&mut ctx, &pair, ib, &mut video, s, t, l, true).unwrap();
        assert_eq!(whole.meta.frames, 2 * l);
        for (side, idx) in [&sel.src_generated, &sel.tgt_generated]
            .into_iter()
            .enumerate()
        {
            let g = &views[side].0;
            assert_eq!(g.meta.frames, 2 * l);
            assert_eq!(g.meta.drawn.as_ref(), Some(idx));
            for &i in idx {
                assert!(g.frame(i).unwrap() == whole.frame(i).unwrap(), "frame {i}");
            }
            let other = (0..2 * l).find(|i| !idx.contains(i)).unwrap();
            assert!(g.frame(other).is_err(), "frame {other} was not drawn");
            // Any frame is drawn on request, the same as the whole video's.
            let drawn = generation::draw_frame(&pair, ib, other).unwrap();
            assert!(
                drawn == whole.frame(other).unwrap(),
                "frame {other} on request"
            );
        }
        assert_ne!(views[0].1.hash, views[1].1.hash);
    }

    /// The run takes the plan's steps in order: a step run before the one the plan has next
    /// is caught (debug builds, as the tests run).
    #[test]
    #[cfg(debug_assertions)]
    #[should_panic(expected = "left the plan's order")]
    fn a_step_out_of_the_plans_order_is_caught() {
        let mut p = Plan::skeleton(&demo_pair(), &demo_params());
        p.fill(Geo, vec!["a".into(), "b".into()]);
        p.fill(ViewSelect, vec!["c".into()]);
    }

    /// A cloud-only pair's run fills the virtual frames' keys as the plan gives them, and
    /// with those frames cached the plan knows the generation's keys.
    #[test]
    fn a_cloud_only_run_fills_the_virtual_frames_step() {
        let mut pair = demo_pair();
        pair.source.frames = None;
        pair.target.frames = None;
        let memo = Memo::default();
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::open(dir.path()).unwrap();
        let p = demo_params();
        let before = plan(&pair, &p, Some(&cache), &memo).unwrap();
        let r = Registration::new(&p)
            .cache(&cache)
            .memo(&memo)
            .run(&pair)
            .unwrap();
        let ran = r.plan.unwrap();
        assert!(ran.is_complete());
        assert_eq!(ran.get(VirtualFrames), before.get(VirtualFrames));
        let after = plan(&pair, &p, Some(&cache), &memo).unwrap();
        assert_eq!(ran, after);
    }
}
