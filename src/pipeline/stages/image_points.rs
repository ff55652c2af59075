//! Stage `image-points`: one image descriptor per keypoint for per-image VFMs, its view's
//! descriptor at its linked pixel (`vfm-view` describes each view at exactly those pixels;
//! unit norm); unlinked keypoints are invalid (reference §8.1). Key: both scans' `lift` keys
//! and every selected view's `vfm-view` key; parameter: the sampling.

use super::vfm::ViewPoints;
use super::Ctx;
use crate::cache::{Cache, CacheKey, Entry};
use crate::error::{Error, Result};
use crate::features::Features;
use crate::vfm::lift::PixelLink;
use rayon::prelude::*;
use serde_json::json;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 2;
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::ImagePoints;

/// (source descriptors, valid, target descriptors, valid).
pub(crate) type Pts = (Features, Vec<bool>, Features, Vec<bool>);

/// Each keypoint's descriptor at its linked pixel (its view's descriptor there, unit norm),
/// zeros and invalid when unlinked or when the model's descriptor there was zero.
fn point_descriptors(links: &[Option<PixelLink>], views: &[ViewPoints]) -> (Features, Vec<bool>) {
    let dim = views.iter().map(|v| v.desc.dim).max().unwrap_or(0);
    let mut data = vec![0.0f32; links.len() * dim];
    let mut valid = vec![false; links.len()];
    data.par_chunks_mut(dim.max(1))
        .zip(valid.par_iter_mut())
        .zip(links.par_iter())
        .for_each(|((row, ok), l)| {
            let d = l.and_then(|l| views.get(l.view as usize)?.get(l.u, l.v));
            if let Some(d) = d.filter(|d| d.len() == row.len()) {
                // unit, or zero (norm < 1e-12); NaN fails the test
                if d.iter().map(|x| x * x).sum::<f32>() > 0.25 {
                    row.copy_from_slice(d);
                    *ok = true;
                }
            }
        });
    (Features::new(dim, data), valid)
}

pub fn key(
    lift_keys: (&CacheKey, &CacheKey),
    view_keys: (&[String], &[String]),
) -> Result<CacheKey> {
    let mut pk: Vec<&str> = vec![&lift_keys.0.hash, &lift_keys.1.hash];
    pk.extend(view_keys.0.iter().map(String::as_str));
    pk.extend(view_keys.1.iter().map(String::as_str));
    CacheKey::new(
        STAGE,
        VERSION,
        &pk,
        &json!({ "sample": "vfm-view-at-pixel" }),
    )
}

fn load(e: &Entry, n_src: usize, n_tgt: usize) -> Result<Pts> {
    let fs = e.read_features("source.npy")?;
    let ft = e.read_features("target.npy")?;
    let (vs, vt): (Vec<bool>, Vec<bool>) = e.read_json("valid.json")?;
    if fs.len() != n_src || ft.len() != n_tgt || vs.len() != fs.len() || vt.len() != ft.len() {
        return Err(Error::Cache(format!(
            "{}: sizes disagree with the keypoints",
            e.dir.display()
        )));
    }
    Ok((fs, vs, ft, vt))
}

fn store((fs, vs, ft, vt): &Pts, c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(k, json!({ "stage": STAGE }))?;
    ne.add_features("source.npy", fs)?;
    ne.add_features("target.npy", ft)?;
    ne.add_json("valid.json", &(vs, vt))?;
    ne.commit()?;
    Ok(())
}

/// Both scans' point descriptors, timed as "image point features"; with the stage key.
pub(crate) fn run(
    ctx: &mut Ctx,
    lift_keys: (&CacheKey, &CacheKey),
    view_keys: (&[String], &[String]),
    links: (&[Option<PixelLink>], &[Option<PixelLink>]),
    views: (&[ViewPoints], &[ViewPoints]),
) -> Result<(Pts, CacheKey)> {
    let (src_links, tgt_links) = links;
    let key = key(lift_keys, view_keys)?;
    let pts = ctx.stage(
        NAME,
        "image point features",
        &key,
        |e| load(e, src_links.len(), tgt_links.len()),
        || {
            let (fs, vs) = point_descriptors(src_links, views.0);
            let (ft, vt) = point_descriptors(tgt_links, views.1);
            Ok((fs, vs, ft, vt))
        },
        store,
    )?;
    Ok((pts, key))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::stages::vfm::view_pixels;
    use crate::vfm::PointDescriptors;

    /// Each keypoint gets its own view's descriptor at its own pixel; repeated pixels are
    /// described once; unlinked keypoints and zero descriptors are invalid.
    #[test]
    fn each_keypoint_gets_the_descriptor_at_its_pixel() {
        let l = |view, u, v| Some(PixelLink { view, u, v });
        let links = vec![
            l(0, 5, 3),
            None,
            l(1, 5, 3),
            l(0, 2, 9),
            l(0, 5, 3),
            l(1, 7, 7),
        ];
        let views: Vec<ViewPoints> = (0..2)
            .map(|view| {
                let pixels = view_pixels(&links, view);
                // descriptor = (view, u, v, 0) normalised; pixel (7, 7) of view 1 is zero
                let data = pixels
                    .iter()
                    .flat_map(|&(u, v)| {
                        let d = [view as f32 + 1.0, u as f32, v as f32, 0.0];
                        let n = d.iter().map(|x| x * x).sum::<f32>().sqrt();
                        let zero = view == 1 && (u, v) == (7, 7);
                        d.map(|x| if zero { 0.0 } else { x / n })
                    })
                    .collect();
                ViewPoints {
                    pixels,
                    desc: PointDescriptors { dim: 4, data },
                }
            })
            .collect();
        assert_eq!(views[0].pixels, vec![(2, 9), (5, 3)]);
        assert_eq!(views[1].pixels, vec![(5, 3), (7, 7)]);
        let (f, valid) = point_descriptors(&links, &views);
        assert_eq!(valid, vec![true, false, true, true, true, false]);
        let row = |i: usize| &f.data[i * 4..i * 4 + 4];
        for (i, want) in [
            (0, views[0].get(5, 3)),
            (2, views[1].get(5, 3)),
            (3, views[0].get(2, 9)),
        ] {
            assert_eq!(row(i), want.unwrap(), "keypoint {i}");
        }
        assert_eq!(row(0), row(4));
        assert_ne!(row(0), row(2));
        assert_eq!(row(1), &[0.0; 4]);
        assert_eq!(row(5), &[0.0; 4]);
    }
}
