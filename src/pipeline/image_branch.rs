//! The full method on one pair: the geometric branch (dense) and the generated-RGB image
//! branch, Match-then-Fuse. This file runs the steps of a [`Plan`] with the image branch, in
//! the plan's order, filling each step's key as it runs; each stage's key, version, compute,
//! load and store are in its own file in `stages/` (the table is in `stages/mod.rs` and
//! `docs/architecture.md`), and which steps a registration has is `plan.rs`.
//!
//! Cosine similarities, calibration, fusion, selection and estimation are cheap and run in
//! memory every time (`tail::fuse_and_finish`), so changing a temperature or the fusion mode
//! recomputes only those.

pub use super::stages::depth_video::depth_video_clip;

use super::geo::cached_branch;
use super::graph::{Plan, StageName};
use super::inputs::PairViews;
use super::memo::Memo;
use super::params::ImageBranchParams;
use super::registration::Registration;
use super::result::{ImageBranchOutput, RegistrationResult, ViewInfo};
use super::stages::depth_video::frames_of;
use super::stages::generation::{short_prompt, Generated};
use super::stages::lift::LiftInput;
use super::stages::pair_vfm::PairInput;
use super::stages::vfm::SideViews;
use super::stages::virtual_frames::{camera_coverage_warnings, framed_pair, FrameStore};
use super::stages::{depth_video, generation, image_points, lift, pair_vfm, vfm, view_select, Ctx};
use super::tail::{fuse_and_finish, FusionInputs, ImageInputs};
use crate::cache::{Cache, CacheKey};
use crate::dataset::{FrameSet, ScanPair};
use crate::error::Result;
use crate::fusion::FusionMode;
use crate::vfm::lift::PixelLink;
use crate::wfm::ViewSelection;
use image::RgbImage;
use std::borrow::Cow;
use std::sync::Arc;

/// The full method on one pair (`ib`: `reg.params.image`), with the [`FusionInputs`] its
/// tail ran on; the steps of `plan` run in order and fill their keys.
/// [`Registration::run`] is the way in. `memo` is `reg.memo` or one for this call.
pub(crate) fn register_with_image(
    pair: &ScanPair,
    reg: &Registration,
    ib: &ImageBranchParams,
    memo: &Memo,
    plan: &mut Plan,
) -> Result<(RegistrationResult, FusionInputs)> {
    // Point-cloud-only scans: depth frames from a virtual camera (stage `virtual-frames`).
    // Without a cache they live in a scratch folder until `store` is dropped, after the run.
    let mut store = FrameStore::new(reg.cache);
    let t = std::time::Instant::now();
    let (framed, notes) = framed_pair(&mut store, pair, ib)?;
    let elapsed = t.elapsed();
    if let Cow::Owned(_) = framed {
        plan.fill(StageName::VirtualFrames, std::mem::take(&mut store.keys));
    }
    let (mut r, inputs) = register_with_frames(&framed, reg, ib, memo, plan)?;
    if let Cow::Owned(_) = framed {
        let mut timer = super::result::Timer::new();
        let hit = store.rendered == 0;
        timer.record_as(StageName::VirtualFrames, "virtual frames", elapsed, hit);
        r.timings.splice(0..0, timer.timings);
        r.total_ms += elapsed.as_secs_f64() * 1e3;
        r.warnings.extend(notes);
        r.warnings.append(&mut store.warnings);
        if let Some(img) = &r.image {
            r.warnings.extend(camera_coverage_warnings(img, ib));
        }
    }
    Ok((r, inputs))
}

/// A generation that `cgenreg generate` hands to a batch: the request, the cache key it is
/// stored under and the backend that serves it (the same as a per-pair run would use).
pub struct PendingGeneration {
    pub pair_id: String,
    pub key: CacheKey,
    pub request: crate::wfm::backend::GenerateRequest,
    pub backend: Box<dyn crate::wfm::backend::WfmBackend>,
    frames_per_fragment: usize,
}

/// The pair's generation if `cache` does not hold it yet (None when it does). Runs only the
/// cached stages before it: virtual frames for point-cloud-only scans, the depth video.
pub fn pending_generation(
    pair: &ScanPair,
    ib: &ImageBranchParams,
    cache: &Cache,
    memo: &Memo,
) -> Result<Option<PendingGeneration>> {
    let mut store = FrameStore::new(Some(cache));
    let (framed, _) = framed_pair(&mut store, pair, ib)?;
    let pair = &*framed;
    let mut ctx = Ctx::new(Some(cache), memo);
    let l = ib.frames_per_fragment;
    let (src_fs, tgt_fs) = (frames_of(&pair.source, l)?, frames_of(&pair.target, l)?);
    let mut video = depth_video::run(&mut ctx, pair, src_fs, tgt_fs, l)?;
    let video_in = (video.meta.hash.as_str(), video.lidar);
    let planned = generation::plan(memo, pair, ib, video_in, src_fs, tgt_fs, l)?;
    if generation::is_cached(cache, &planned.key) {
        return Ok(None);
    }
    let request = planned.request(pair, ib, &mut video)?;
    Ok(Some(PendingGeneration {
        pair_id: pair.id.clone(),
        key: planned.key,
        request,
        backend: planned.backend,
        frames_per_fragment: l,
    }))
}

/// Check and store a batch's result for `p` (what a per-pair run would have stored).
pub fn store_pending(
    cache: &Cache,
    p: &PendingGeneration,
    g: crate::wfm::backend::Generation,
) -> Result<()> {
    generation::store_generated(cache, &p.key, g, p.frames_per_fragment)
}

/// One scan's side of the image branch as the result shows it.
struct Side<'a> {
    frames: &'a FrameSet,
    images: Vec<RgbImage>,
    generated: &'a [usize],
    depth: &'a [usize],
    links: Vec<Option<PixelLink>>,
}

/// The image branch of a pair whose scans both have depth frames, then the fused tail; each
/// step fills its key in `plan`.
fn register_with_frames(
    pair: &ScanPair,
    reg: &Registration,
    ib: &ImageBranchParams,
    memo: &Memo,
    plan: &mut Plan,
) -> Result<(RegistrationResult, FusionInputs)> {
    let (params, generate) = (reg.params, reg.generate);
    let mut ctx = Ctx::new(reg.cache, memo);
    let l = depth_video::settings(ib);
    let src_fs = frames_of(&pair.source, l)?;
    let tgt_fs = frames_of(&pair.target, l)?;
    // Fail early on bad K / m (before anything expensive).
    let planned = view_select::planned(ib)?;
    let vfm_id = vfm::vfm_id(memo, &ib.vfm)?;

    // Geometric branch (dense path: the image branch needs the N x M similarity).
    let (src_geo, src_geo_key) = cached_branch(&mut ctx, "source", &pair.source, params)?;
    let (tgt_geo, tgt_geo_key) = cached_branch(&mut ctx, "target", &pair.target, params)?;
    plan.fill(
        StageName::Geo,
        vec![src_geo_key.hash.clone(), tgt_geo_key.hash.clone()],
    );

    let gen = if generation::frame_by_frame(&ib.backend) {
        // Each frame is a function of its own depth (or colour) frame: no depth video, only
        // the selected views are drawn (the selection of a 2L-frame video is `planned`).
        let fs = (src_fs, tgt_fs);
        Generated::Views(generation::run_views(
            &mut ctx, pair, ib, fs, &planned, generate,
        )?)
    } else {
        let mut video = depth_video::run(&mut ctx, pair, src_fs, tgt_fs, l)?;
        plan.fill(StageName::DepthVideo, vec![video.key.clone()]);
        let (g, k) = generation::run(&mut ctx, pair, ib, &mut video, src_fs, tgt_fs, l, generate)?;
        Generated::Video(g, k)
    };
    plan.fill(StageName::Generation, gen.key_hashes());
    let meta = &gen.first().meta;
    let image_size = (meta.width, meta.height);
    let (sel, sel_key) = view_select::run(&mut ctx, planned, meta.frames, ib)?;
    plan.fill(StageName::ViewSelect, vec![sel_key.hash]);

    let pair_conditioned = vfm::is_pair_conditioned(&ib.vfm);

    // Lifting, over all K views.
    let (src_links, src_lift_key) = lift::run(
        &mut ctx,
        "lift source",
        &LiftInput {
            geo_key: &src_geo_key,
            keypoints: &src_geo.keypoints.points,
            frames: src_fs,
            depth_idx: &sel.src_depth,
        },
        lift::settings(params),
        image_size,
    )?;
    let (tgt_links, tgt_lift_key) = lift::run(
        &mut ctx,
        "lift target",
        &LiftInput {
            geo_key: &tgt_geo_key,
            keypoints: &tgt_geo.keypoints.points,
            frames: tgt_fs,
            depth_idx: &sel.tgt_depth,
        },
        lift::settings(params),
        image_size,
    )?;
    plan.fill(
        StageName::Lift,
        vec![src_lift_key.hash.clone(), tgt_lift_key.hash.clone()],
    );
    let lift_keys = (&src_lift_key, &tgt_lift_key);
    // Per-image models describe each view at the pixels just linked to it.
    let (src_views, tgt_views, mut vfm_label) = describe_views(
        &mut ctx,
        &gen,
        &sel,
        (&src_links, &tgt_links),
        lift_keys,
        ib,
        &vfm_id,
    )?;

    // Per-keypoint image descriptors (per-image models) or per-pair descriptors (pair models).
    let image = if pair_conditioned {
        let key = pair_vfm::key(lift_keys, &gen.pair_key()?, &vfm_id, &sel)?;
        let inp = PairInput {
            src_images: &src_views.images,
            tgt_images: &tgt_views.images,
            src_links: &src_links,
            tgt_links: &tgt_links,
        };
        let (d, label) = pair_vfm::run(&mut ctx, &key, &inp, &ib.vfm, &vfm_id)?;
        plan.fill(StageName::PairVfm, vec![key.hash]);
        vfm_label = label;
        ImageInputs::PairConditioned(d)
    } else {
        let view_keys = [src_views.keys.clone(), tgt_views.keys.clone()].concat();
        plan.fill(StageName::Vfm, view_keys);
        let ((fs, vs, ft, vt), key) = image_points::run(
            &mut ctx,
            lift_keys,
            (&src_views.keys, &tgt_views.keys),
            (&src_links, &tgt_links),
            (&src_views.points, &tgt_views.points),
        )?;
        plan.fill(StageName::ImagePoints, vec![key.hash]);
        ImageInputs::PerImage(fs, vs, ft, vt)
    };
    let sides = [
        Side {
            frames: src_fs,
            images: src_views.images,
            generated: &sel.src_generated,
            depth: &sel.src_depth,
            links: src_links,
        },
        Side {
            frames: tgt_fs,
            images: tgt_views.images,
            generated: &sel.tgt_generated,
            depth: &sel.tgt_depth,
            links: tgt_links,
        },
    ];
    let coverage = coverage_warnings(&image);
    let views = PairViews::new(src_fs.clone(), tgt_fs.clone());
    // Now for the visibility fusion, and for virtual frames of a run without a cache in any mode:
    // their scratch folder is gone after the run, and a later re-fusion to `visibility` compares
    // poses in them. Otherwise they are read on first use (sensor frames and cached ones stay).
    let scratch = reg.cache.is_none() && !views.origin().is_sensor();
    if params.fusion.mode == FusionMode::Visibility || scratch {
        let t = std::time::Instant::now();
        views.load_with(memo)?;
        ctx.timer
            .record("visibility: read depth views", t.elapsed(), false);
    }
    let inputs = FusionInputs {
        source_geo: src_geo,
        target_geo: tgt_geo,
        image_label: Some(branch_label(ib, gen.first(), &vfm_id, &image)),
        image: Some(image),
        views: Some(Arc::new(views)),
    };
    let output = image_output(ib, gen.side(0), sides, vfm_label);
    let mut res = fuse_and_finish(pair, params, &inputs, None, reg.estimates)?;
    // The cached stages' timings first, then the in-memory ones.
    let Ctx {
        timer, warnings, ..
    } = ctx;
    let mut timings = timer.timings;
    timings.append(&mut res.timings);
    res.timings = timings;
    res.total_ms = timer.t0.elapsed().as_secs_f64() * 1e3;
    res.warnings.extend(warnings);
    res.warnings.extend(coverage);
    res.warnings
        .extend(gen.first().provenance.warnings.iter().cloned());
    res.image = Some(output);
    Ok((res, inputs))
}

/// VFM descriptors per selected view at the pixels `links` links to it (per-image models;
/// pair models describe the views jointly in `pair_vfm`, from the images), and the VFM's label
/// as it ran.
fn describe_views(
    ctx: &mut Ctx,
    gen: &Generated,
    sel: &ViewSelection,
    links: (&[Option<PixelLink>], &[Option<PixelLink>]),
    lift_keys: (&CacheKey, &CacheKey),
    ib: &ImageBranchParams,
    vfm_id: &str,
) -> Result<(SideViews, SideViews, String)> {
    let mut model = None;
    let (src, tgt) = if vfm::is_pair_conditioned(&ib.vfm) {
        let images_only = |side: usize, idx: &[usize]| -> Result<SideViews> {
            Ok(SideViews {
                points: Vec::new(),
                images: vfm::images(gen.side(side).0, idx)?,
                keys: Vec::new(),
            })
        };
        (
            images_only(0, &sel.src_generated)?,
            images_only(1, &sel.tgt_generated)?,
        )
    } else {
        let mut side = |ctx: &mut Ctx, name: &str, s: usize, idx: &[usize], l, k| {
            vfm::run_side(ctx, name, gen.side(s), idx, (l, k), ib, vfm_id, &mut model)
        };
        (
            side(
                ctx,
                "vfm source views",
                0,
                &sel.src_generated,
                links.0,
                lift_keys.0,
            )?,
            side(
                ctx,
                "vfm target views",
                1,
                &sel.tgt_generated,
                links.1,
                lift_keys.1,
            )?,
        )
    };
    let label = match &model {
        Some(_) => format!("{vfm_id} ({})", crate::vfm::backend_name()),
        None => format!("{vfm_id} (descriptors from the cache)"),
    };
    Ok((src, tgt, label))
}

/// A side whose views give a pixel to fewer than 1 % of its keypoints: the image posterior says
/// nothing there, Noisy-AND drops those keypoints and the union keeps only geometry's matches.
/// The usual cause is a virtual camera that does not fit the scan (an xyz-only LiDAR scan gets
/// the pinhole trajectory under `auto`).
fn coverage_warnings(im: &ImageInputs) -> Vec<String> {
    let (v_src, v_tgt) = im.validity();
    [("source", &v_src), ("target", &v_tgt)]
        .into_iter()
        .filter_map(|(side, v)| {
            let n = v.iter().filter(|v| **v).count();
            (v.is_empty() || n * 100 < v.len()).then(|| {
                format!(
                    "the image branch links {n} of the {} {side} keypoints to a pixel: the \
                     image posterior says nothing about the others (Noisy-AND drops them; the \
                     union keeps geometry's matches). For a LiDAR scan stored without \
                     intensity, choose the f-theta camera (--virtual-camera ftheta)",
                    v.len()
                )
            })
        })
        .collect()
}

/// The image branch's label (the fusion mode is appended by the in-memory tail).
fn branch_label(
    ib: &ImageBranchParams,
    gen: &super::stages::generation::GenOut,
    vfm_id: &str,
    im: &ImageInputs,
) -> String {
    let (v_src, v_tgt) = im.validity();
    let n = |v: &[bool]| v.iter().filter(|v| **v).count();
    let read = match vfm::cell_of(ib) {
        Some(1) => ", per pixel".to_string(),
        Some(c) => format!(", {c}-px cells"),
        None => String::new(),
    };
    format!(
        "{} + {}{read} (K={}, m={}, L={}; {} / {} source / target keypoints with a pixel",
        gen.provenance.backend,
        vfm_id,
        ib.k,
        ib.margin,
        ib.frames_per_fragment,
        n(&v_src),
        n(&v_tgt),
    )
}

/// The views, links and provenance the GUI shows.
fn image_output(
    ib: &ImageBranchParams,
    (gen, gen_key): (&super::stages::generation::GenOut, &CacheKey),
    sides: [Side; 2],
    vfm: String,
) -> ImageBranchOutput {
    let view_label = format!(
        "{} | {} | cache {}",
        gen.provenance.backend,
        short_prompt(&ib.prompt),
        &gen_key.hash[..8]
    );
    let views = |s: Side| -> (Vec<ViewInfo>, Vec<Option<PixelLink>>) {
        let fs = s.frames;
        let v = s
            .images
            .into_iter()
            .zip(s.generated.iter().zip(s.depth))
            .map(|(image, (&g, &d))| ViewInfo {
                image,
                generated_index: g,
                depth_index: d,
                label: view_label.clone(),
                depth_path: fs.frames.get(d).map(|f| f.depth_path.clone()),
                scan_from_camera: fs.frames.get(d).map(|f| f.scan_from_camera),
                camera: fs.camera.clone(),
            })
            .collect();
        (v, s.links)
    };
    let [src, tgt] = sides;
    let (source_views, source_links) = views(src);
    let (target_views, target_links) = views(tgt);
    ImageBranchOutput {
        source_views,
        target_views,
        source_links,
        target_links,
        provenance: gen.provenance.clone(),
        vfm,
    }
}
