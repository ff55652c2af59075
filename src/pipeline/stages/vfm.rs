//! Stage `vfm-view`: the dense descriptor grid of one selected generated view from a
//! per-image VFM (XFeat). Key: the generation's key; parameters: the frame index and the
//! model id (name + content hash of the model file). Also the one place models are loaded
//! ([`load_vfm`], [`load_pair_vfm`]): a new VFM is a `VfmSpec` variant and an arm there.

use super::generation::GenOut;
use super::Ctx;
use crate::error::{Error, Result};
use crate::pipeline::cache::{Cache, CacheKey, Entry};
use crate::pipeline::memo::Memo;
use crate::pipeline::params::VfmSpec;
use crate::vfm::{DenseDescriptors, PairModel, PerImageModel};
use image::RgbImage;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

pub const STAGE: &str = "vfm-view";
pub const VERSION: u32 = 1;

/// Whether `spec` describes views jointly (pair-conditioned: the `pair_vfm` stage) rather
/// than one at a time (this stage).
pub fn is_pair_conditioned(spec: &VfmSpec) -> bool {
    matches!(spec, VfmSpec::Mast3r { .. })
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
    if !model.is_file() {
        return Err(Error::Invalid(format!(
            "{}: {} ONNX model not found (see models/README.md, or pass --vfm-model)",
            model.display(),
            spec.name()
        )));
    }
    Ok(format!("{}@{}", spec.name(), &memo.hash_file(model)?[..16]))
}

#[derive(Serialize, Deserialize)]
struct GridMeta {
    width: u32,
    height: u32,
    dim: usize,
    stride_x: f32,
    stride_y: f32,
}

pub fn key(gen_key: &CacheKey, frame: usize, vfm_id: &str) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[&gen_key.hash],
        &json!({ "frame": frame, "vfm": vfm_id }),
    )
}

fn load(e: &Entry) -> Result<DenseDescriptors> {
    let m: GridMeta = e.read_json("grid.json")?;
    let (_, _, d) = e.read_f32_matrix("desc.npy")?;
    DenseDescriptors::new(m.width, m.height, m.dim, d, m.stride_x, m.stride_y)
}

fn store(g: &DenseDescriptors, frame: usize, vfm_id: &str, c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(k, json!({ "vfm": vfm_id, "frame": frame }))?;
    ne.add_json(
        "grid.json",
        &GridMeta {
            width: g.width,
            height: g.height,
            dim: g.dim,
            stride_x: g.stride_x,
            stride_y: g.stride_y,
        },
    )?;
    ne.add_f32_matrix("desc.npy", (g.width * g.height) as usize, g.dim, &g.data)?;
    ne.commit()?;
    Ok(())
}

/// One side's selected views: descriptor grids, the images, and the stages' key hashes.
pub(crate) struct SideViews {
    pub(crate) grids: Vec<DenseDescriptors>,
    pub(crate) images: Vec<RgbImage>,
    pub(crate) keys: Vec<String>,
}

/// The descriptor grids of the generated frames `idx`, timed together as `name` (a hit
/// when every view was). `model` is loaded on the first miss and kept for the other side.
// The key parts (generation, frames, model) plus the context and the loaded model.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_side(
    ctx: &mut Ctx,
    name: &str,
    gen: &GenOut,
    gen_key: &CacheKey,
    idx: &[usize],
    spec: &VfmSpec,
    vfm_id: &str,
    model: &mut Option<Arc<dyn PerImageModel>>,
) -> Result<SideViews> {
    let t = Instant::now();
    let memo = ctx.memo;
    let mut all_hit = true;
    let mut out = SideViews {
        grids: Vec::new(),
        images: Vec::new(),
        keys: Vec::new(),
    };
    for &gi in idx {
        let img = gen.frame(gi)?;
        let key = key(gen_key, gi, vfm_id)?;
        let (g, hit) = ctx.cached(
            &key,
            load,
            || {
                let m = match model {
                    Some(m) => m.clone(),
                    None => model.insert(load_vfm(memo, spec, vfm_id)?).clone(),
                };
                m.describe(&img)
            },
            |g, c, k| store(g, gi, vfm_id, c, k),
        )?;
        all_hit &= hit;
        out.grids.push(g);
        out.images.push(img);
        out.keys.push(key.hash);
    }
    ctx.timer.record(name, t.elapsed(), all_hit);
    Ok(out)
}

/// The images of the generated frames `idx` (pair models describe them jointly later).
pub(crate) fn images(gen: &GenOut, idx: &[usize]) -> Result<Vec<RgbImage>> {
    idx.iter().map(|&gi| gen.frame(gi)).collect()
}
