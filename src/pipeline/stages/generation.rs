//! Stage `generation`: the WFM's RGB frames for the pair's depth video. Key: the depth
//! video's hash (plus the colour frames' content hashes for `oracle`, whose output they are);
//! parameters: the backend's id, the prompt text and the seed. The entry holds every frame as
//! PNG, the provenance and the frame size; frames are read lazily on a hit.
//!
//! A frame-by-frame backend ([`frame_by_frame`]: the built-in shading, the oracle's real RGB),
//! whose every frame is a function of its own depth (or colour) frame alone, draws only the
//! selected views, one entry per side ([`run_views`]): key inputs, the content hashes of the
//! side's selected depth files (colour files for `oracle`); parameters, the backend's id, the
//! prompt, the seed, the frames drawn (their indices in the 2L-frame video) and the depth clip.
//! Its frames are the ones the whole video would hold at those indices, bit for bit; the
//! entry says which it holds (`meta.json`'s `drawn`, the provenance's `params.drawn`). A real
//! world model (Cosmos, its cached outputs) generates the whole video, as the paper does.

use super::depth_video::DepthVideo;
use super::Ctx;
use crate::cache::{Cache, CacheKey, Entry};
use crate::dataset::{FrameSet, ScanPair};
use crate::error::{Error, Result};
use crate::pipeline::memo::Memo;
use crate::pipeline::params::{ImageBranchParams, WfmSpec};
use crate::wfm::backend::{GenerateRequest, Generation, Provenance, WfmBackend};
use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::Generation;

#[derive(Serialize, Deserialize)]
pub(crate) struct GenMeta {
    /// Frames of the video (2L for a frame-by-frame backend, which draws only `drawn`).
    pub(crate) frames: usize,
    pub(crate) width: u32,
    pub(crate) height: u32,
    /// The video's frames this entry holds, when not all of them (a frame-by-frame backend's
    /// selected views), in the order drawn.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) drawn: Option<Vec<usize>>,
}

/// Generated frames: in memory when just computed, read lazily from the cache entry on a hit.
pub(crate) struct GenOut {
    pub(crate) provenance: Provenance,
    pub(crate) meta: GenMeta,
    frames: Option<Vec<RgbImage>>,
    entry: Option<Entry>,
}

impl GenOut {
    /// Frame `i` of the video (an index into the whole video also for a frame-by-frame
    /// backend's entry, which holds only the frames it drew).
    pub(crate) fn frame(&self, i: usize) -> Result<RgbImage> {
        let pos = match &self.meta.drawn {
            None => i,
            Some(d) => d.iter().position(|&g| g == i).ok_or_else(|| {
                Error::Missing(format!(
                    "generated frame {i} was not drawn: this generation holds only the \
                     selected views {d:?}"
                ))
            })?,
        };
        if let Some(f) = &self.frames {
            return f
                .get(pos)
                .cloned()
                .ok_or_else(|| Error::Shape(format!("generated frame {i} out of range")));
        }
        match &self.entry {
            Some(e) => e.read_png(&frame_name(i)),
            None => Err(Error::Missing("generated frames are not available".into())),
        }
    }
}

fn frame_name(i: usize) -> String {
    format!("frames/{i:05}.png")
}

fn encode_png_fast(img: &RgbImage) -> Result<Vec<u8>> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let mut buf = Vec::new();
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Sub)
        .write_image(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| Error::Encode(format!("encoding a frame as PNG: {e}")))?;
    Ok(buf)
}

/// The backend for `spec`; the built-in generator renders LiDAR pairs at the outdoor
/// resolution of the paper (appendix C: 1280x640), RGB-D pairs at 960x704.
pub(crate) fn make_backend(spec: &WfmSpec, lidar: bool) -> Result<Box<dyn WfmBackend>> {
    Ok(match spec {
        WfmSpec::Oracle => Box::new(crate::wfm::oracle::OracleBackend::default()),
        WfmSpec::Builtin if lidar => Box::new(crate::wfm::builtin::DepthShadeBackend {
            width: 1280,
            height: 640,
        }),
        WfmSpec::Builtin => Box::new(crate::wfm::builtin::DepthShadeBackend::default()),
        WfmSpec::Cached { dir, spec } => {
            Box::new(crate::wfm::cached::CachedBackend::open(dir, spec)?)
        }
        WfmSpec::Cosmos {
            command,
            work_dir,
            timeout_s,
        } => Box::new(crate::wfm::cosmos::CosmosBackend::new(
            crate::wfm::cosmos::CosmosConfig::new(
                command.clone(),
                work_dir.clone(),
                std::time::Duration::from_secs(*timeout_s),
            ),
        )?),
    })
}

/// The prompt's scene text, shortened for labels and messages.
pub(crate) fn short_prompt(p: &crate::wfm::Prompt) -> String {
    let s = p.scene.trim();
    let mut out: String = s.chars().take(40).collect();
    if s.chars().count() > 40 {
        out.push('…');
    }
    if out.is_empty() {
        "(empty prompt)".into()
    } else {
        format!("\"{out}\"")
    }
}

/// Key: `inputs` (the video hash, then for oracle the colour frames' hashes), backend id,
/// prompt text, seed.
pub fn key(inputs: &[String], backend_id: &str, ib: &ImageBranchParams) -> Result<CacheKey> {
    let ImageBranchParams {
        // keyed by its id (`backend_id`: the model, not the spelling of the option)
        backend: _,
        prompt,
        seed,
        vfm: _,
        k: _,
        margin: _,
        // the depth video's hash (an input) carries L
        frames_per_fragment: _,
        lift_radius: _,
        virtual_camera: _,
        lidar_cameras: _,
        lidar_origin: _,
        dense_stride: _,
    } = ib;
    let gi: Vec<&str> = inputs.iter().map(String::as_str).collect();
    CacheKey::new(
        STAGE,
        VERSION,
        &gi,
        &json!({ "backend": backend_id, "prompt": prompt.text(), "seed": seed }),
    )
}

fn load(e: &Entry) -> Result<GenOut> {
    let provenance: Provenance = e.read_json("provenance.json")?;
    let meta: GenMeta = e.read_json("meta.json")?;
    let held: Vec<usize> = match &meta.drawn {
        Some(d) => d.clone(),
        None => (0..meta.frames).collect(),
    };
    if held
        .iter()
        .any(|&i| !e.manifest.files.iter().any(|f| f.name == frame_name(i)))
    {
        return Err(Error::Cache(format!("{}: frames missing", e.dir.display())));
    }
    Ok(GenOut {
        provenance,
        meta,
        frames: None,
        entry: Some(e.clone()),
    })
}

fn store(g: &GenOut, c: &Cache, k: &CacheKey) -> Result<()> {
    let frames = g
        .frames
        .as_ref()
        .ok_or_else(|| Error::Missing("no frames".into()))?;
    let pngs: Vec<Vec<u8>> = frames
        .par_iter()
        .map(encode_png_fast)
        .collect::<Result<_>>()?;
    let prov = serde_json::to_value(&g.provenance)
        .map_err(|e| Error::Encode(format!("provenance: {e}")))?;
    let mut ne = c.put(k, prov)?;
    let held: Vec<usize> = match &g.meta.drawn {
        Some(d) => d.clone(),
        None => (0..pngs.len()).collect(),
    };
    for (&i, b) in held.iter().zip(&pngs) {
        ne.add_bytes(&frame_name(i), b)?;
    }
    ne.add_json("provenance.json", &g.provenance)?;
    ne.add_json("meta.json", &g.meta)?;
    ne.commit()?;
    Ok(())
}

/// Check a backend's output: at least 2L frames, all of one size.
pub(crate) fn validate(backend_id: &str, g: Generation, l: usize) -> Result<GenOut> {
    if g.frames.len() < 2 * l {
        return Err(Error::External {
            what: backend_id.to_string(),
            message: format!("returned {} frames, {} needed", g.frames.len(), 2 * l),
        });
    }
    let (w, h) = g.frames[0].dimensions();
    if g.frames.iter().any(|f| f.dimensions() != (w, h)) {
        return Err(Error::External {
            what: backend_id.to_string(),
            message: "frames of different sizes".into(),
        });
    }
    Ok(GenOut {
        meta: GenMeta {
            frames: g.frames.len(),
            width: w,
            height: h,
            drawn: None,
        },
        provenance: g.provenance,
        frames: Some(g.frames),
        entry: None,
    })
}

/// The backend, the cache key and the colour frames of a pair's generation.
pub(crate) struct Planned {
    pub(crate) backend: Box<dyn WfmBackend>,
    pub(crate) key: CacheKey,
    is_oracle: bool,
    src_col: Option<Vec<PathBuf>>,
    tgt_col: Option<Vec<PathBuf>>,
}

impl Planned {
    /// What the backend is asked (builds the depth video's frames if the stage was a hit).
    pub(crate) fn request(
        &self,
        pair: &ScanPair,
        ib: &ImageBranchParams,
        video: &mut DepthVideo,
    ) -> Result<GenerateRequest> {
        // The oracle reads the colour frames; it needs no depth video.
        let depth_video = if video.has_frames() || !self.is_oracle {
            video.take_frames()?
        } else {
            Vec::new()
        };
        Ok(GenerateRequest {
            pair_id: pair.id.clone(),
            depth_video,
            depth_video_path: None,
            prompt: ib.prompt.clone(),
            seed: ib.seed,
            source_color: self.src_col.clone(),
            target_color: self.tgt_col.clone(),
        })
    }
}

/// The generation of a depth video with content hash `video_hash` (`lidar`: either scan is
/// a LiDAR scan, which sets the built-in generator's frame size).
pub(crate) fn plan(
    memo: &Memo,
    pair: &ScanPair,
    ib: &ImageBranchParams,
    (video_hash, lidar): (&str, bool),
    src_fs: &FrameSet,
    tgt_fs: &FrameSet,
    l: usize,
) -> Result<Planned> {
    let backend = make_backend(&ib.backend, lidar)?;
    let is_oracle = matches!(ib.backend, WfmSpec::Oracle);
    let colour = |fs: &FrameSet| -> Option<Vec<PathBuf>> {
        fs.frames[..l]
            .iter()
            .map(|f| f.color_path.clone())
            .collect()
    };
    let (src_col, tgt_col) = (colour(src_fs), colour(tgt_fs));
    let mut inputs = vec![video_hash.to_string()];
    if is_oracle {
        // The oracle's output is the colour frames, so they (not the depth) key it.
        let (Some(s), Some(t)) = (&src_col, &tgt_col) else {
            let side = match (&src_col, &tgt_col) {
                (None, None) => "neither scan has",
                (None, _) => "its source scan has no",
                _ => "its target scan has no",
            };
            return Err(Error::Missing(format!(
                "oracle backend: pair `{}` has no colour frames ({side} real RGB frames; the \
                 oracle only shows a dataset's own RGB: use `builtin` or a WFM for this pair)",
                pair.id
            )));
        };
        let h: Vec<String> = s
            .par_iter()
            .chain(t.par_iter())
            .map(|p| memo.hash_file(p))
            .collect::<Result<_>>()?;
        inputs.extend(h);
    }
    let key = key(&inputs, &backend.id(), ib)?;
    Ok(Planned {
        backend,
        key,
        is_oracle,
        src_col,
        tgt_col,
    })
}

/// The number and size of the generated frames when `c` holds a usable generation under `k`.
pub(crate) fn cached_meta(c: &Cache, k: &CacheKey) -> Option<GenMeta> {
    match c.get(k) {
        Ok(Some(e)) => load(&e).ok().map(|g| g.meta),
        _ => None,
    }
}

/// Whether `c` holds a usable generation under `k`.
pub(crate) fn is_cached(c: &Cache, k: &CacheKey) -> bool {
    matches!(c.get(k), Ok(Some(e)) if load(&e).is_ok())
}

/// Validate and store a generation made outside [`run`] (a batch).
pub(crate) fn store_generated(c: &Cache, k: &CacheKey, g: Generation, l: usize) -> Result<()> {
    let out = validate(&g.provenance.backend.clone(), g, l)?;
    store(&out, c, k)
}

/// The generation for the pair's depth video, timed as "generation". With `generate` false
/// a generation missing from the cache is [`Error::GenerationNotCached`].
// The inputs are the stage's own: the pair, its frames, the video and the parameters.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run(
    ctx: &mut Ctx,
    pair: &ScanPair,
    ib: &ImageBranchParams,
    video: &mut DepthVideo,
    src_fs: &FrameSet,
    tgt_fs: &FrameSet,
    l: usize,
    generate: bool,
) -> Result<(GenOut, CacheKey)> {
    let planned = plan(
        ctx.memo,
        pair,
        ib,
        (&video.meta.hash, video.lidar),
        src_fs,
        tgt_fs,
        l,
    )?;
    let backend_id = planned.backend.id();
    let key = planned.key.clone();
    let t = Instant::now();
    let (gen, hit) = ctx.cached(
        &key,
        load,
        || {
            if !generate {
                return Err(Error::GenerationNotCached {
                    backend: backend_id.clone(),
                    prompt: short_prompt(&ib.prompt),
                    seed: ib.seed,
                });
            }
            let req = planned.request(pair, ib, video)?;
            validate(&backend_id, planned.backend.generate(&req)?, l)
        },
        store,
    )?;
    ctx.timer.record_as(NAME, "generation", t.elapsed(), hit);
    Ok((gen, key))
}

/// Whether `spec`'s frames are each a function of their own depth (or colour) frame alone, so
/// that only the selected views need drawing ([`run_views`]): the built-in shading and the
/// oracle's real RGB. A real world model (Cosmos, its cached outputs) generates the whole video.
pub(crate) fn frame_by_frame(spec: &WfmSpec) -> bool {
    spec.frame_by_frame()
}

/// The sides in the order of a frame-by-frame generation's keys.
const SIDES: [&str; 2] = ["source", "target"];

/// Key of one side's drawn views (a frame-by-frame backend): `inputs`, the content hashes of
/// the side's selected depth files (colour files for `oracle`), in view order; `drawn`, their
/// indices in the video of `video_frames` frames; `clip`, the depth clip the built-in shading
/// reads (None for `oracle`, which reads no depth).
pub fn views_key(
    inputs: &[String],
    backend_id: &str,
    ib: &ImageBranchParams,
    (drawn, video_frames): (&[usize], usize),
    clip: Option<f64>,
) -> Result<CacheKey> {
    let ImageBranchParams {
        // keyed by its id (`backend_id`)
        backend: _,
        prompt,
        seed,
        vfm: _,
        // `drawn` and `video_frames` carry the selection and L
        k: _,
        margin: _,
        frames_per_fragment: _,
        lift_radius: _,
        virtual_camera: _,
        lidar_cameras: _,
        lidar_origin: _,
        dense_stride: _,
    } = ib;
    let gi: Vec<&str> = inputs.iter().map(String::as_str).collect();
    let mut p = json!({ "backend": backend_id, "prompt": prompt.text(), "seed": seed,
                        "drawn": drawn, "video_frames": video_frames });
    if let Some(c) = clip {
        p["clip"] = json!(c);
    }
    CacheKey::new(STAGE, VERSION, &gi, &p)
}

/// The input a pair VFM's key reads of a frame-by-frame generation: both sides' keys.
pub(crate) fn pair_key(sides: [&CacheKey; 2]) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[&sides[0].hash, &sides[1].hash],
        &json!({ "sides": SIDES }),
    )
}

/// A frame-by-frame backend's views of a pair: the backend, each side's key and what it reads.
pub(crate) struct ViewsPlanned {
    pub(crate) backend: Box<dyn WfmBackend>,
    pub(crate) keys: [CacheKey; 2],
    depth: [Vec<PathBuf>; 2],
    colour: Option<[Vec<PathBuf>; 2]>,
    drawn: [Vec<usize>; 2],
    video_frames: usize,
    clip: f64,
}

/// The views `sel` selects of a pair's 2L-frame video under a frame-by-frame backend: hashes
/// the selected depth files (colour files for `oracle`).
pub(crate) fn plan_views(
    memo: &Memo,
    pair: &ScanPair,
    ib: &ImageBranchParams,
    (src_fs, tgt_fs): (&FrameSet, &FrameSet),
    sel: &crate::wfm::ViewSelection,
    l: usize,
) -> Result<ViewsPlanned> {
    let (lidar, clip) = super::depth_video::pair_clip(src_fs, tgt_fs);
    let backend = make_backend(&ib.backend, lidar)?;
    let is_oracle = matches!(ib.backend, WfmSpec::Oracle);
    let pick = |fs: &FrameSet,
                idx: &[usize],
                f: &dyn Fn(&crate::dataset::RgbdFrame) -> Option<PathBuf>| {
        idx.iter()
            .map(|&i| fs.frames.get(i).and_then(f))
            .collect::<Option<Vec<PathBuf>>>()
    };
    let depth_of = |f: &crate::dataset::RgbdFrame| Some(f.depth_path.clone());
    let colour_of = |f: &crate::dataset::RgbdFrame| f.color_path.clone();
    let bad_index = || Error::Shape("a selected view is not one of the scan's frames".into());
    let depth = [
        pick(src_fs, &sel.src_depth, &depth_of).ok_or_else(bad_index)?,
        pick(tgt_fs, &sel.tgt_depth, &depth_of).ok_or_else(bad_index)?,
    ];
    let colour = if is_oracle {
        // The same check as the whole video's: the first L frames of both scans have colour.
        let has = |fs: &FrameSet| fs.frames[..l].iter().all(|f| f.color_path.is_some());
        if !has(src_fs) || !has(tgt_fs) {
            let side = match (has(src_fs), has(tgt_fs)) {
                (false, false) => "neither scan has",
                (false, true) => "its source scan has no",
                _ => "its target scan has no",
            };
            return Err(Error::Missing(format!(
                "oracle backend: pair `{}` has no colour frames ({side} real RGB frames; the \
                 oracle only shows a dataset's own RGB: use `builtin` or a WFM for this pair)",
                pair.id
            )));
        }
        Some([
            pick(src_fs, &sel.src_depth, &colour_of).ok_or_else(bad_index)?,
            pick(tgt_fs, &sel.tgt_depth, &colour_of).ok_or_else(bad_index)?,
        ])
    } else {
        None
    };
    let drawn = [sel.src_generated.clone(), sel.tgt_generated.clone()];
    let video_frames = 2 * l;
    let id = backend.id();
    let mut keys = Vec::with_capacity(2);
    for side in 0..2 {
        let files = match &colour {
            Some(c) => &c[side],
            None => &depth[side],
        };
        let inputs: Vec<String> = files
            .par_iter()
            .map(|p| memo.hash_file(p))
            .collect::<Result<_>>()?;
        let c = (!is_oracle).then_some(clip);
        keys.push(views_key(
            &inputs,
            &id,
            ib,
            (&drawn[side], video_frames),
            c,
        )?);
    }
    let keys: [CacheKey; 2] = keys
        .try_into()
        .map_err(|_| Error::Invalid("two sides".into()))?;
    Ok(ViewsPlanned {
        backend,
        keys,
        depth,
        colour,
        drawn,
        video_frames,
        clip,
    })
}

impl ViewsPlanned {
    /// Draws side `side`'s views (0 source, 1 target): the built-in shading of their depth
    /// frames, encoded as the depth video encodes them, or the oracle's colour frames.
    fn draw(&self, pair: &ScanPair, ib: &ImageBranchParams, side: usize) -> Result<GenOut> {
        let backend_id = self.backend.id();
        let depth_video = match self.colour {
            Some(_) => Vec::new(),
            None => crate::wfm::depth_video::pair_video_from_files_clip(
                &self.depth[side],
                &[] as &[PathBuf],
                self.clip,
            )?,
        };
        let colour = |s: usize| {
            self.colour
                .as_ref()
                .map(|c| if s == side { c[s].clone() } else { Vec::new() })
        };
        let req = GenerateRequest {
            pair_id: format!("{} ({} views)", pair.id, SIDES[side]),
            depth_video,
            depth_video_path: None,
            prompt: ib.prompt.clone(),
            seed: ib.seed,
            source_color: colour(0),
            target_color: colour(1),
        };
        let mut g = self.backend.generate(&req)?;
        let drawn = &self.drawn[side];
        if g.frames.len() != drawn.len() {
            return Err(Error::External {
                what: backend_id,
                message: format!("returned {} frames, {} asked", g.frames.len(), drawn.len()),
            });
        }
        let (w, h) = g.frames.first().map_or((0, 0), |f| f.dimensions());
        if g.frames.iter().any(|f| f.dimensions() != (w, h)) {
            return Err(Error::External {
                what: backend_id,
                message: "frames of different sizes".into(),
            });
        }
        if let Some(o) = g.provenance.params.as_object_mut() {
            o.insert(
                "drawn".into(),
                json!({ "side": SIDES[side], "frames": drawn, "of": self.video_frames,
                        "why": "each frame depends on its own depth (or colour) frame alone: \
                                only the selected views are drawn" }),
            );
        }
        g.provenance.frame_count = g.frames.len();
        Ok(GenOut {
            meta: GenMeta {
                frames: self.video_frames,
                width: w,
                height: h,
                drawn: Some(drawn.clone()),
            },
            provenance: g.provenance,
            frames: Some(g.frames),
            entry: None,
        })
    }
}

/// A frame-by-frame backend's selected views of the pair, one entry per side (source, target),
/// timed together as "generation" (a hit when both were). With `generate` false a side missing
/// from the cache is [`Error::GenerationNotCached`].
pub(crate) fn run_views(
    ctx: &mut Ctx,
    pair: &ScanPair,
    ib: &ImageBranchParams,
    (src_fs, tgt_fs): (&FrameSet, &FrameSet),
    sel: &crate::wfm::ViewSelection,
    generate: bool,
) -> Result<[(GenOut, CacheKey); 2]> {
    let l = ib.frames_per_fragment;
    let planned = plan_views(ctx.memo, pair, ib, (src_fs, tgt_fs), sel, l)?;
    let t = Instant::now();
    let mut all_hit = true;
    let mut out = Vec::with_capacity(2);
    for side in 0..2 {
        let key = planned.keys[side].clone();
        let (g, hit) = ctx.cached(
            &key,
            load,
            || {
                if !generate {
                    return Err(Error::GenerationNotCached {
                        backend: planned.backend.id(),
                        prompt: short_prompt(&ib.prompt),
                        seed: ib.seed,
                    });
                }
                planned.draw(pair, ib, side)
            },
            store,
        )?;
        all_hit &= hit;
        out.push((g, key));
    }
    ctx.timer
        .record_as(NAME, "generation", t.elapsed(), all_hit);
    out.try_into()
        .map_err(|_| Error::Invalid("two sides".into()))
}

/// A pair's generation: the whole video in one entry (a world model), or a frame-by-frame
/// backend's selected views in one entry per side (source, target).
// One value per registration, held on the stack of one call: its size does not matter.
#[allow(clippy::large_enum_variant)]
pub(crate) enum Generated {
    Video(GenOut, CacheKey),
    Views([(GenOut, CacheKey); 2]),
}

impl Generated {
    /// What side `side` (0 source, 1 target) reads its views from, and that entry's key.
    pub(crate) fn side(&self, side: usize) -> (&GenOut, &CacheKey) {
        match self {
            Generated::Video(g, k) => (g, k),
            Generated::Views(s) => {
                let (g, k) = &s[side.min(1)];
                (g, k)
            }
        }
    }

    /// The source side's (or the video's) generation: provenance and frame size, which the
    /// sides share.
    pub(crate) fn first(&self) -> &GenOut {
        self.side(0).0
    }

    /// The generation step's key hashes (one, or source then target).
    pub(crate) fn key_hashes(&self) -> Vec<String> {
        match self {
            Generated::Video(_, k) => vec![k.hash.clone()],
            Generated::Views(s) => s.iter().map(|(_, k)| k.hash.clone()).collect(),
        }
    }

    /// The key a pair VFM's key reads: the video's, or one over both sides' keys.
    pub(crate) fn pair_key(&self) -> Result<CacheKey> {
        match self {
            Generated::Video(_, k) => Ok(k.clone()),
            Generated::Views(s) => pair_key([&s[0].1, &s[1].1]),
        }
    }
}

/// Frame `i` of a pair's 2L-frame video under a frame-by-frame backend, drawn now and not
/// cached: any frame on request (the pipeline draws only the selected views). `pair`'s scans
/// need their depth frames (virtual frames already rendered for point-cloud-only scans).
pub fn draw_frame(pair: &ScanPair, ib: &ImageBranchParams, i: usize) -> Result<RgbImage> {
    if !frame_by_frame(&ib.backend) {
        return Err(Error::Usage(
            "a world model's frames come from its whole video: read them from the generation's \
             cache entry"
                .into(),
        ));
    }
    let l = ib.frames_per_fragment;
    let src_fs = super::depth_video::frames_of(&pair.source, l)?;
    let tgt_fs = super::depth_video::frames_of(&pair.target, l)?;
    if i >= 2 * l {
        return Err(Error::Shape(format!(
            "frame {i} of a {}-frame video",
            2 * l
        )));
    }
    let (side, one) = (usize::from(i >= l), vec![i]);
    let depth = vec![if side == 0 { i } else { i - l }];
    let sel = crate::wfm::ViewSelection {
        src_generated: if side == 0 { one.clone() } else { Vec::new() },
        src_depth: if side == 0 { depth.clone() } else { Vec::new() },
        tgt_generated: if side == 1 { one } else { Vec::new() },
        tgt_depth: if side == 1 { depth } else { Vec::new() },
    };
    let planned = plan_views(&Memo::default(), pair, ib, (src_fs, tgt_fs), &sel, l)?;
    planned.draw(pair, ib, side)?.frame(i)
}
