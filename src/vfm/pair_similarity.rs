//! The image similarity of a pair-conditioned model (MASt3R), reference §8.1: a source point
//! linked to (view s, pixel p) and a target point linked to (view t, pixel q) are compared
//! through the one forward pass that saw both views, pair k = s·K_tgt + t:
//! `S[i, j] = cos(desc1[k](p), desc2[k](q))`. Unlinked points get S = 0 and are invalid.
//!
//! Only the descriptors at linked pixels are kept: per source point one vector for every target
//! view, per target point one for every source view (N·K·24 floats instead of K²·704·960·24).

use super::lift::PixelLink;
use super::DenseDescriptors;
use crate::error::{Error, Result};
use crate::matrix::DenseMatrix;
use rayon::prelude::*;

/// Unit descriptors at the linked pixels, for every partner view.
#[derive(Clone, Debug, PartialEq)]
pub struct PairPointDescriptors {
    pub k_src: usize,
    pub k_tgt: usize,
    pub dim: usize,
    /// N x k_tgt x dim: source point i as seen in pair (its view, t).
    pub src: Vec<f32>,
    pub src_view: Vec<Option<u16>>,
    /// M x k_src x dim: target point j as seen in pair (s, its view).
    pub tgt: Vec<f32>,
    pub tgt_view: Vec<Option<u16>>,
}

fn normalize(v: &mut [f32]) -> bool {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    // F.normalize(eps=1e-6) as the reference.
    let d = n.max(1e-6);
    v.iter_mut().for_each(|x| *x /= d);
    n > 0.0
}

/// Sample `pairs` (src-major, as [`super::describe_all_pairs`] returns them) at the links.
pub fn pair_point_descriptors(
    pairs: &[(DenseDescriptors, DenseDescriptors)],
    k_src: usize,
    k_tgt: usize,
    src_links: &[Option<PixelLink>],
    tgt_links: &[Option<PixelLink>],
) -> Result<PairPointDescriptors> {
    if pairs.len() != k_src * k_tgt || pairs.is_empty() {
        return Err(Error::Shape(format!(
            "pair-conditioned descriptors: {} pair outputs for {k_src}x{k_tgt} views",
            pairs.len()
        )));
    }
    let dim = pairs[0].0.dim;
    if pairs.iter().any(|(a, b)| a.dim != dim || b.dim != dim) {
        return Err(Error::Shape(
            "pair-conditioned descriptors: pair outputs disagree on the descriptor size".into(),
        ));
    }
    let bad_view = |l: &PixelLink, k: usize| (l.view as usize) >= k;
    if src_links.iter().flatten().any(|l| bad_view(l, k_src))
        || tgt_links.iter().flatten().any(|l| bad_view(l, k_tgt))
    {
        return Err(Error::Shape(
            "pair-conditioned descriptors: a pixel link names a view that was not described".into(),
        ));
    }
    let side = |links: &[Option<PixelLink>], partners: usize, is_src: bool| {
        let mut data = vec![0.0f32; links.len() * partners * dim];
        let mut view = vec![None; links.len()];
        data.par_chunks_mut((partners * dim).max(1))
            .zip(view.par_iter_mut())
            .zip(links.par_iter())
            .for_each(|((row, vw), l)| {
                let Some(l) = l else { return };
                let mut any = false;
                for (p, out) in row.chunks_mut(dim.max(1)).enumerate() {
                    let (s, t) = if is_src {
                        (l.view as usize, p)
                    } else {
                        (p, l.view as usize)
                    };
                    let pr = &pairs[s * k_tgt + t];
                    let grid = if is_src { &pr.0 } else { &pr.1 };
                    grid.sample_into(l.u as f32, l.v as f32, out);
                    any |= normalize(out);
                }
                if any {
                    *vw = Some(l.view);
                }
            });
        (data, view)
    };
    let (src, src_view) = side(src_links, k_tgt, true);
    let (tgt, tgt_view) = side(tgt_links, k_src, false);
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

impl PairPointDescriptors {
    /// Row `i` of [`Self::similarity`].
    pub fn similarity_row(&self, i: usize) -> Vec<f32> {
        let m = self.tgt_view.len();
        let d = self.dim;
        let Some(Some(si)) = self.src_view.get(i).copied() else {
            return vec![0.0; m];
        };
        let a = &self.src[i * self.k_tgt * d..(i + 1) * self.k_tgt * d];
        (0..m)
            .map(|j| match self.tgt_view[j] {
                Some(tj) => {
                    let x = &a[tj as usize * d..(tj as usize + 1) * d];
                    let o = (j * self.k_src + si as usize) * d;
                    x.iter().zip(&self.tgt[o..o + d]).map(|(p, q)| p * q).sum()
                }
                None => 0.0,
            })
            .collect()
    }

    /// The dense N x M similarity and the validity of each row / column.
    pub fn similarity(&self) -> Result<(DenseMatrix, Vec<bool>, Vec<bool>)> {
        let (n, m, d) = (self.src_view.len(), self.tgt_view.len(), self.dim);
        let mut s = DenseMatrix::zeros(n, m)?;
        if d == 0 || m == 0 {
            return Ok((s, vec![false; n], vec![false; m]));
        }
        s.data.par_chunks_mut(m).enumerate().for_each(|(i, row)| {
            let Some(si) = self.src_view[i] else { return };
            let si = si as usize;
            let a = &self.src[i * self.k_tgt * d..(i + 1) * self.k_tgt * d];
            for (j, out) in row.iter_mut().enumerate() {
                let Some(tj) = self.tgt_view[j] else { continue };
                let x = &a[tj as usize * d..(tj as usize + 1) * d];
                let o = (j * self.k_src + si) * d;
                let y = &self.tgt[o..o + d];
                *out = x.iter().zip(y).map(|(p, q)| p * q).sum();
            }
        });
        let vs = self.src_view.iter().map(Option::is_some).collect();
        let vt = self.tgt_view.iter().map(Option::is_some).collect();
        Ok((s, vs, vt))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Lcg;

    fn grid(w: u32, h: u32, dim: usize, seed: &mut Lcg) -> DenseDescriptors {
        let data = (0..(w * h) as usize * dim)
            .map(|_| seed.unit31_f32() - 0.5)
            .collect();
        DenseDescriptors::new(w, h, dim, data, 1.0, 1.0).unwrap()
    }

    /// Every entry against the reference's definition, evaluated directly.
    #[test]
    fn matches_brute_force_definition() {
        let (w, h, dim, ks, kt) = (6u32, 5u32, 4usize, 2usize, 3usize);
        let mut seed = Lcg(7);
        let pairs: Vec<_> = (0..ks * kt)
            .map(|_| (grid(w, h, dim, &mut seed), grid(w, h, dim, &mut seed)))
            .collect();
        let link = |view: u16, u: u32, v: u32| Some(PixelLink { view, u, v });
        let src = vec![link(0, 1, 2), None, link(1, 5, 4), link(1, 0, 0)];
        let tgt = vec![
            link(2, 3, 3),
            link(0, 0, 1),
            None,
            link(1, 4, 0),
            link(2, 2, 2),
        ];
        let d = pair_point_descriptors(&pairs, ks, kt, &src, &tgt).unwrap();
        let (s, vs, vt) = d.similarity().unwrap();
        for i in 0..src.len() {
            assert_eq!(d.similarity_row(i), s.row(i).to_vec());
        }
        assert_eq!(vs, vec![true, false, true, true]);
        assert_eq!(vt, vec![true, true, false, true, true]);
        for (i, a) in src.iter().enumerate() {
            for (j, b) in tgt.iter().enumerate() {
                let want = match (a, b) {
                    (Some(a), Some(b)) => {
                        let k = a.view as usize * kt + b.view as usize;
                        let x = pairs[k].0.cell(a.u, a.v).to_vec();
                        let y = pairs[k].1.cell(b.u, b.v).to_vec();
                        let nx = x.iter().map(|v| v * v).sum::<f32>().sqrt();
                        let ny = y.iter().map(|v| v * v).sum::<f32>().sqrt();
                        x.iter().zip(&y).map(|(p, q)| p * q).sum::<f32>() / (nx * ny)
                    }
                    _ => 0.0,
                };
                assert!(
                    (s.get(i, j) - want).abs() < 1e-5,
                    "({i},{j}) {} vs {want}",
                    s.get(i, j)
                );
            }
        }
    }

    #[test]
    fn wrong_pair_count_and_bad_view_are_errors() {
        let mut seed = Lcg(1);
        let pairs: Vec<_> = (0..3)
            .map(|_| (grid(4, 4, 2, &mut seed), grid(4, 4, 2, &mut seed)))
            .collect();
        assert!(pair_point_descriptors(&pairs, 2, 2, &[], &[]).is_err());
        let bad = vec![Some(PixelLink {
            view: 3,
            u: 0,
            v: 0,
        })];
        assert!(pair_point_descriptors(&pairs[..1], 1, 1, &bad, &[]).is_err());
    }
}
