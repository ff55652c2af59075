//! Stage `vfm-view`: one selected generated view described by a per-image VFM (XFeat, DISK,
//! ALIKE) at the pixels lifting linked to it ([`PerImageModel::describe_at`]: XFeat's H/8
//! grid sampled bilinearly; a dense model's full-resolution map read at the pixel and dropped
//! when the call returns, so no map outlives its view). Key: the generation's key and the
//! side's lift key; parameters: the frame, its view index and the model id (name + content
//! hash of the model file). Also the one place models are loaded
//! ([`load_vfm`], [`load_pair_vfm`]): a new VFM is a `VfmSpec` variant and an arm there.

use super::generation::GenOut;
use super::Ctx;
use crate::cache::{Cache, CacheKey, Entry};
use crate::error::{Error, Result};
use crate::pipeline::memo::Memo;
use crate::pipeline::params::ImageBranchParams;
use crate::vfm::lift::PixelLink;
use crate::vfm::VfmSpec;
use crate::vfm::{PairModel, PerImageModel, PointDescriptors};
use image::RgbImage;
use serde_json::json;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 2;
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::Vfm;

/// Whether `spec` describes views jointly (pair-conditioned: the `pair_vfm` stage) rather
/// than one at a time (this stage).
pub fn is_pair_conditioned(spec: &VfmSpec) -> bool {
    spec.is_pair_conditioned()
}

/// The per-image model of `spec` (cache id `vfm_id`), loaded once per `memo` (bench
/// registers many pairs with one model).
pub(crate) fn load_vfm(
    memo: &Memo,
    spec: &VfmSpec,
    vfm_id: &str,
) -> Result<Arc<dyn PerImageModel>> {
    match spec {
        VfmSpec::Xfeat { model } => memo.per_image_model(vfm_id, || load_xfeat(model)),
        VfmSpec::Disk { model } | VfmSpec::Alike { model } => {
            memo.per_image_model(vfm_id, || load_dense(spec, model))
        }
        VfmSpec::Mast3r { model } => Err(Error::Invalid(format!(
            "{} is a pair-conditioned model, not a per-image one",
            model.display()
        ))),
    }
}

/// The pair-conditioned model of `spec` (cache id `vfm_id`), loaded once per `memo`.
pub(crate) fn load_pair_vfm(
    memo: &Memo,
    spec: &VfmSpec,
    vfm_id: &str,
) -> Result<Arc<dyn PairModel>> {
    match spec {
        VfmSpec::Mast3r { model } => memo.pair_model(vfm_id, || load_mast3r(model)),
        other => Err(Error::Invalid(format!(
            "{} is a per-image model, not a pair-conditioned one",
            other.model().display()
        ))),
    }
}

#[cfg(feature = "onnx")]
fn load_xfeat(path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Ok(Arc::new(crate::vfm::xfeat::XFeat::load(path)?))
}

#[cfg(feature = "onnx")]
fn load_dense(spec: &VfmSpec, path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Ok(Arc::new(crate::vfm::dense::DenseModel::load_spec(
        spec, path,
    )?))
}

#[cfg(not(feature = "onnx"))]
fn load_dense(_: &VfmSpec, path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Err(no_onnx(path))
}

#[cfg(feature = "onnx")]
fn load_mast3r(path: &Path) -> Result<Arc<dyn PairModel>> {
    Ok(Arc::new(crate::vfm::mast3r::Mast3r::load(path)?))
}

#[cfg(not(feature = "onnx"))]
fn load_xfeat(path: &Path) -> Result<Arc<dyn PerImageModel>> {
    Err(no_onnx(path))
}

#[cfg(not(feature = "onnx"))]
fn load_mast3r(path: &Path) -> Result<Arc<dyn PairModel>> {
    Err(no_onnx(path))
}

#[cfg(not(feature = "onnx"))]
fn no_onnx(path: &Path) -> Error {
    Error::Invalid(format!(
        "the image branch needs its VFM ({}) through ONNX, but cgenreg was built without the \
         `onnx` feature: rebuild with `--features onnx`",
        path.display()
    ))
}

/// Id of the VFM for cache keys, from the model file's content (no need to load it).
pub fn vfm_id(memo: &Memo, spec: &VfmSpec) -> Result<String> {
    let model = spec.model();
    if !model.exists() {
        return Err(Error::Missing(format!(
            "{}: {} ONNX model not found (see models/README.md, or pass --vfm-model)",
            model.display(),
            spec.name()
        )));
    }
    // a FIFO or a device is named as one, not as missing
    crate::io::limits::check_regular(model)?;
    Ok(format!("{}@{}", spec.name(), &memo.hash_file(model)?[..16]))
}

/// One view's descriptors at the pixels lifting linked to it: sorted distinct `(u, v)` and
/// one unit descriptor per pixel (zero where the model's descriptor had norm < 1e-12).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ViewPoints {
    pub(crate) pixels: Vec<(u32, u32)>,
    pub(crate) desc: PointDescriptors,
}

impl ViewPoints {
    /// The descriptor at pixel `(u, v)`, if it is one of this view's.
    pub(crate) fn get(&self, u: u32, v: u32) -> Option<&[f32]> {
        let i = self.pixels.binary_search(&(u, v)).ok()?;
        self.desc
            .data
            .get(i * self.desc.dim..(i + 1) * self.desc.dim)
    }
}

/// The distinct pixels of `links` in view `view`, sorted.
pub(crate) fn view_pixels(links: &[Option<PixelLink>], view: usize) -> Vec<(u32, u32)> {
    let mut px: Vec<(u32, u32)> = links
        .iter()
        .flatten()
        .filter(|l| l.view as usize == view)
        .map(|l| (l.u, l.v))
        .collect();
    px.sort_unstable();
    px.dedup();
    px
}

/// Key of view `view` (generated frame `frame`) of a side whose lift has key `lift_key`: the
/// lift fixes the pixels the view is described at.
/// `cell`: the dense-model cell size ([`cell_of`]; None for models with their own grid).
pub fn key(
    gen_key: &CacheKey,
    lift_key: &CacheKey,
    (frame, view): (usize, usize),
    vfm_id: &str,
    cell: Option<u32>,
) -> Result<CacheKey> {
    let mut p =
        json!({ "frame": frame, "view": view, "vfm": vfm_id, "sample": "at-lifted-pixels" });
    if let Some(c) = cell {
        p["cell"] = json!(c);
    }
    CacheKey::new(STAGE, VERSION, &[&gen_key.hash, &lift_key.hash], &p)
}

/// What the stage reads of the settings: the VFM (its id, name and model file hash, is the
/// key's `vfm`) and the cell size it is read through: `dense_stride` for dense per-pixel
/// models, None for the others (it does not change what they give).
pub fn settings(ib: &ImageBranchParams) -> (&VfmSpec, Option<u32>) {
    let ImageBranchParams {
        // the generation's key carries these
        backend: _,
        prompt: _,
        seed: _,
        vfm,
        // the selected frames and the lift key carry these
        k: _,
        margin: _,
        frames_per_fragment: _,
        lift_radius: _,
        virtual_camera: _,
        lidar_cameras: _,
        lidar_origin: _,
        dense_stride,
    } = ib;
    (vfm, vfm.is_dense().then_some(*dense_stride))
}

/// The cell size a VFM is read through ([`settings`]).
pub fn cell_of(ib: &ImageBranchParams) -> Option<u32> {
    settings(ib).1
}

fn load(e: &Entry, pixels: &[(u32, u32)]) -> Result<ViewPoints> {
    let (n, two, px) = e.read_f32_matrix("pixels.npy")?;
    let (m, dim, data) = e.read_f32_matrix("desc.npy")?;
    let stored: Vec<(u32, u32)> = px.chunks(2).map(|c| (c[0] as u32, c[1] as u32)).collect();
    if two != 2 || n != m || stored.as_slice() != pixels {
        return Err(Error::Cache(format!(
            "{}: the stored pixels are not the {} pixels the lift links to this view",
            e.dir.display(),
            pixels.len()
        )));
    }
    Ok(ViewPoints {
        pixels: stored,
        desc: PointDescriptors { dim, data },
    })
}

fn store(p: &ViewPoints, frame: usize, vfm_id: &str, c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(k, json!({ "vfm": vfm_id, "frame": frame }))?;
    // pixel coordinates are below 2^24, exact in f32
    let px: Vec<f32> = p
        .pixels
        .iter()
        .flat_map(|&(u, v)| [u as f32, v as f32])
        .collect();
    ne.add_f32_matrix("pixels.npy", p.pixels.len(), 2, &px)?;
    ne.add_f32_matrix("desc.npy", p.pixels.len(), p.desc.dim, &p.desc.data)?;
    ne.commit()?;
    Ok(())
}

/// One side's selected views: descriptors at the linked pixels, the images, and the stages'
/// key hashes.
pub(crate) struct SideViews {
    pub(crate) points: Vec<ViewPoints>,
    pub(crate) images: Vec<RgbImage>,
    pub(crate) keys: Vec<String>,
}

/// Describes the generated frames `idx` at the pixels `links` links to each (one model run
/// per view: a dense model's full-resolution map lives only inside that call), timed together
/// as `name` (a hit when every view was). `model` is loaded on the first miss and kept for the
/// other side.
// The key parts (generation, frames, lift, model) plus the context and the loaded model.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_side(
    ctx: &mut Ctx,
    name: &str,
    (gen, gen_key): (&GenOut, &CacheKey),
    idx: &[usize],
    (links, lift_key): (&[Option<PixelLink>], &CacheKey),
    ib: &ImageBranchParams,
    vfm_id: &str,
    model: &mut Option<Arc<dyn PerImageModel>>,
) -> Result<SideViews> {
    let (spec, cell) = settings(ib);
    let t = Instant::now();
    let memo = ctx.memo;
    let mut all_hit = true;
    let mut out = SideViews {
        points: Vec::new(),
        images: Vec::new(),
        keys: Vec::new(),
    };
    for (view, &gi) in idx.iter().enumerate() {
        let img = gen.frame(gi)?;
        let key = key(gen_key, lift_key, (gi, view), vfm_id, cell)?;
        let pixels = view_pixels(links, view);
        let (p, hit) = ctx.cached(
            &key,
            |e| load(e, &pixels),
            || {
                let m = match model {
                    Some(m) => m.clone(),
                    None => model.insert(load_vfm(memo, spec, vfm_id)?).clone(),
                };
                let at: Vec<(f32, f32)> =
                    pixels.iter().map(|&(u, v)| (u as f32, v as f32)).collect();
                let desc = m.describe_at_cells(&img, &at, cell.unwrap_or(1))?;
                Ok(ViewPoints {
                    pixels: pixels.clone(),
                    desc,
                })
            },
            |p, c, k| store(p, gi, vfm_id, c, k),
        )?;
        all_hit &= hit;
        out.points.push(p);
        out.images.push(img);
        out.keys.push(key.hash);
    }
    ctx.timer.record_as(NAME, name, t.elapsed(), all_hit);
    Ok(out)
}

/// The images of the generated frames `idx` (pair models describe them jointly later).
pub(crate) fn images(gen: &GenOut, idx: &[usize]) -> Result<Vec<RgbImage>> {
    idx.iter().map(|&gi| gen.frame(gi)).collect()
}
