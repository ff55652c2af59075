//! Stage `generation`: the WFM's RGB frames for the pair's depth video. Key: the depth
//! video's hash (plus the colour frames' content hashes for `oracle`, whose output they are);
//! parameters: the backend's id, the prompt text and the seed. The entry holds every frame as
//! PNG, the provenance and the frame size; frames are read lazily on a hit.

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

pub const STAGE: &str = "generation";
pub const VERSION: u32 = 1;
pub const NAME: crate::pipeline::plan::StageName = crate::pipeline::plan::StageName::Generation;

#[derive(Serialize, Deserialize)]
pub(crate) struct GenMeta {
    pub(crate) frames: usize,
    pub(crate) width: u32,
    pub(crate) height: u32,
}

/// Generated frames: in memory when just computed, read lazily from the cache entry on a hit.
pub(crate) struct GenOut {
    pub(crate) provenance: Provenance,
    pub(crate) meta: GenMeta,
    frames: Option<Vec<RgbImage>>,
    entry: Option<Entry>,
}

impl GenOut {
    pub(crate) fn frame(&self, i: usize) -> Result<RgbImage> {
        if let Some(f) = &self.frames {
            return f
                .get(i)
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
    if (0..meta.frames).any(|i| !e.manifest.files.iter().any(|f| f.name == frame_name(i))) {
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
    for (i, b) in pngs.iter().enumerate() {
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
