//! Stage `image-points-pair`: per-keypoint descriptors from a pair-conditioned VFM (MASt3R):
//! every source view is described jointly with every target view, and each keypoint gets one
//! descriptor per partner view at its linked pixel. Key: both scans' `lift` keys, the
//! generation key and the model id; parameters: the selected frames and the sampling.

use super::vfm::load_pair_vfm;
use super::Ctx;
use crate::cache::{Cache, CacheKey, Entry};
use crate::error::{Error, Result};
use crate::vfm::lift::PixelLink;
use crate::vfm::pair_similarity::{pair_point_descriptors, PairPointDescriptors};
use crate::vfm::VfmSpec;
use crate::wfm::ViewSelection;
use image::RgbImage;
use serde_json::json;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::PairVfm;

pub fn key(
    lift_keys: (&CacheKey, &CacheKey),
    gen_key: &CacheKey,
    vfm_id: &str,
    sel: &ViewSelection,
) -> Result<CacheKey> {
    let pk: Vec<&str> = vec![&lift_keys.0.hash, &lift_keys.1.hash, &gen_key.hash, vfm_id];
    CacheKey::new(
        STAGE,
        VERSION,
        &pk,
        &json!({ "src_frames": sel.src_generated, "tgt_frames": sel.tgt_generated,
                 "sample": "bilinear-l2" }),
    )
}

fn load(e: &Entry, n_links: (usize, usize), k: (usize, usize)) -> Result<PairPointDescriptors> {
    let (k_src, k_tgt) = k;
    let (ns, cs, src) = e.read_f32_matrix("source.npy")?;
    let (nt, ct, tgt) = e.read_f32_matrix("target.npy")?;
    let (src_view, tgt_view): (Vec<Option<u16>>, Vec<Option<u16>>) = e.read_json("views.json")?;
    let dim = cs / k_tgt.max(1);
    if ns != n_links.0
        || nt != n_links.1
        || src_view.len() != ns
        || tgt_view.len() != nt
        || cs != dim * k_tgt
        || ct != dim * k_src
    {
        return Err(Error::Cache(format!(
            "{}: sizes disagree with the keypoints and views",
            e.dir.display()
        )));
    }
    Ok(PairPointDescriptors {
        k_src,
        k_tgt,
        dim,
        src,
        src_view,
        tgt,
        tgt_view,
    })
}

fn store(d: &PairPointDescriptors, vfm_id: &str, c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(k, json!({ "stage": STAGE, "vfm": vfm_id }))?;
    ne.add_f32_matrix("source.npy", d.src_view.len(), d.k_tgt * d.dim, &d.src)?;
    ne.add_f32_matrix("target.npy", d.tgt_view.len(), d.k_src * d.dim, &d.tgt)?;
    ne.add_json("views.json", &(&d.src_view, &d.tgt_view))?;
    ne.commit()?;
    Ok(())
}

/// What the pair stage reads besides its key parts: the views' images and the links.
pub(crate) struct PairInput<'a> {
    pub(crate) src_images: &'a [RgbImage],
    pub(crate) tgt_images: &'a [RgbImage],
    pub(crate) src_links: &'a [Option<PixelLink>],
    pub(crate) tgt_links: &'a [Option<PixelLink>],
}

/// The pair descriptors, timed as "vfm view pairs + point features"; with the label of the
/// VFM as it ran (loaded now, or read from the cache).
pub(crate) fn run(
    ctx: &mut Ctx,
    key: &CacheKey,
    inp: &PairInput,
    spec: &VfmSpec,
    vfm_id: &str,
) -> Result<(PairPointDescriptors, String)> {
    let (k_src, k_tgt) = (inp.src_images.len(), inp.tgt_images.len());
    let mut loaded = false;
    let memo = ctx.memo;
    let d = ctx.stage(
        NAME,
        "vfm view pairs + point features",
        key,
        |e| {
            load(
                e,
                (inp.src_links.len(), inp.tgt_links.len()),
                (k_src, k_tgt),
            )
        },
        || {
            let m = load_pair_vfm(memo, spec, vfm_id)?;
            loaded = true;
            let pairs = crate::vfm::describe_all_pairs(m.as_ref(), inp.src_images, inp.tgt_images)?;
            pair_point_descriptors(&pairs, k_src, k_tgt, inp.src_links, inp.tgt_links)
        },
        |d, c, k| store(d, vfm_id, c, k),
    )?;
    let label = if loaded {
        format!(
            "{vfm_id} ({}; {}x{} view pairs)",
            crate::vfm::backend_name(),
            k_src,
            k_tgt
        )
    } else {
        format!("{vfm_id} (pair descriptors from the cache)")
    };
    Ok((d, label))
}
