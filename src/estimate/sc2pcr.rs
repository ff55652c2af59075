//! SC2-PCR (Chen et al., CVPR 2022) exactly as the C-GenReg reference calls it
//! (reference §9.2, `models/SC2PCR/SC2_PCR_MY.py`), with bs = 1.
//!
//! Input: correspondence endpoints `src[i] ↔ tgt[i]` (source and target frames), sorted by score
//! descending; the first `max_points` are used. Output: `target_from_source`.
//!
//! The reference builds several dense N x N f32 matrices (N = 8000: 256 MB each). Here:
//! - `hard = C < d`, `tight = C < d/2` and `near = Ds < nms_radius` are bitsets (u64 words);
//! - `SC = clamp(1 − C²/d², 0)` is non-zero exactly where `hard` is set, so it is stored as one
//!   (column, value) pair per set bit of `hard` (a sparse row);
//! - `SC2[s, j] = popcount(tight[s] & tight[j])` for `hard[s, j]`, 0 otherwise, is evaluated only
//!   for the set bits of `hard[s]`, visited by decreasing upper bound `|tight[j]|` so the scan
//!   stops once nothing left can enter the top-k1; only the top-k1 are kept.
//!
//! Ties are broken deterministically by the lower correspondence index (stable sorts); torch's
//! unstable argsort may order ties differently.

use super::hypotheses::{Hypotheses, Hypothesis, TopN};
use super::kabsch;
use super::Estimate;
use crate::simd::Isa;
use crate::{Error, Result};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// Reference §9.1 (upstream `config_3DMatch.json`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sc2PcrParams {
    /// Hypothesis scoring and post-refinement inlier threshold (m). The reference refines with
    /// 0.10 for 3DMatch and 1.2 for KITTI; here refinement uses this value.
    pub inlier_threshold: f32,
    /// Compatibility distance d (m): `hard = C < d`, `tight = C < d/2`.
    pub d_thre: f32,
    /// Power-iteration steps (global eigenvector and per-seed weights).
    pub num_iterations: usize,
    /// Fraction of correspondences taken as seeds.
    pub ratio: f32,
    /// NMS radius in the source cloud (m).
    pub nms_radius: f32,
    pub max_points: usize,
    pub k1: usize,
    pub k2: usize,
    pub refine_iterations: usize,
}

impl Default for Sc2PcrParams {
    fn default() -> Self {
        Sc2PcrParams {
            inlier_threshold: 0.10,
            d_thre: 0.10,
            num_iterations: 10,
            ratio: 0.2,
            nms_radius: 0.10,
            max_points: 8000,
            k1: 30,
            k2: 20,
            refine_iterations: 20,
        }
    }
}

/// Run SC2-PCR. Errors (which `estimate_pose` turns into the weighted-SVD fallback, as the
/// reference does on an exception): mismatched lengths, non-finite coordinates, fewer than 5
/// correspondences (no seed or no 4-neighbourhood), invalid parameters.
pub fn sc2pcr(src: &[Point3<f32>], tgt: &[Point3<f32>], params: &Sc2PcrParams) -> Result<Estimate> {
    sc2pcr_with(src, tgt, params, 0).map(|(e, _)| e)
}

/// [`sc2pcr`] that also keeps the best `top_n` seed hypotheses (None when `top_n` is 0),
/// ranked by SC2-PCR's own rule: consensus size (correspondences within `inlier_threshold`
/// under the seed's pose), ties to the earlier seed (the reference's argmax takes the first
/// maximum). Rank 1 is the hypothesis post-refined into the estimate, which is the same as
/// [`sc2pcr`]'s.
pub fn sc2pcr_with(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    params: &Sc2PcrParams,
    top_n: usize,
) -> Result<(Estimate, Option<Hypotheses>)> {
    if src.len() != tgt.len() {
        return Err(Error::Invalid(format!(
            "sc2pcr: {} source points but {} target points",
            src.len(),
            tgt.len()
        )));
    }
    let p = params;
    if !(p.d_thre > 0.0 && p.inlier_threshold > 0.0 && p.nms_radius >= 0.0 && p.ratio > 0.0)
        || p.k1 == 0
        || p.k2 == 0
        || p.max_points == 0
    {
        return Err(Error::Invalid(format!("sc2pcr: invalid parameters {p:?}")));
    }
    let n = src.len().min(p.max_points);
    let (src, tgt) = (&src[..n], &tgt[..n]);
    if let Some(i) = (0..n).find(|&i| {
        !(src[i].coords.iter().all(|v| v.is_finite())
            && tgt[i].coords.iter().all(|v| v.is_finite()))
    }) {
        return Err(Error::Degenerate(format!(
            "sc2pcr: correspondence {i} has a non-finite coordinate"
        )));
    }
    let (mut k1, mut k2) = (p.k1, p.k2.min(p.k1));
    if k1 > n {
        k1 = 4;
        k2 = 4;
    }
    let num_seeds = ((n as f64) * (p.ratio as f64)).floor() as usize;
    if n < 4 || k1 > n || num_seeds == 0 {
        return Err(Error::Degenerate(format!(
            "sc2pcr: {n} correspondences are too few (need {k1} neighbours and at least one seed)"
        )));
    }
    let pts = Soa::new(src, tgt);
    let g = Graph::build(&pts, p.d_thre, p.nms_radius);
    let conf = g.leading_eigenvector(p.num_iterations);
    let seeds = g.pick_seeds(&conf, num_seeds);
    // Blocks of seeds share each tight row they load (8 seed rows stay in L1 at n = 8000).
    let sets = seeds
        .par_chunks(8)
        .flat_map_iter(|block| {
            g.sc2_top_k_block(block, k1)
                .into_iter()
                .map(|knn| g.second_stage(&knn, k2))
        })
        .collect::<Vec<_>>();
    let weights = seed_weights(&pts, &sets, p.d_thre, p.num_iterations);
    let hyps: Vec<Option<Isometry3<f64>>> = sets
        .par_iter()
        .zip(weights.par_iter())
        .map(|(set, w)| {
            kabsch::solve(
                set.len(),
                |k| (pts.src64(set[k]), pts.tgt64(set[k]), w[k] as f64),
                1e-6,
            )
        })
        .collect();
    let fitness: Vec<usize> = hyps
        .par_iter()
        .map(|h| {
            h.as_ref()
                .map_or(0, |t| pts.count_inliers(t, p.inlier_threshold))
        })
        .collect();
    // argmax returns the first maximum, like torch.
    let mut best: Option<(usize, usize)> = None;
    for (k, h) in hyps.iter().enumerate() {
        if h.is_some() && best.is_none_or(|(_, f)| fitness[k] > f) {
            best = Some((k, fitness[k]));
        }
    }
    let Some((best, _)) = best else {
        return Err(Error::Degenerate(
            "sc2pcr: no seed gave a finite transform".into(),
        ));
    };
    let mut trans = hyps[best].unwrap_or_else(Isometry3::identity);
    trans = post_refinement(&pts, trans, p.inlier_threshold, p.refine_iterations);
    let d = pts.residuals(&trans);
    let inliers: Vec<usize> = (0..n).filter(|&i| d[i] < p.inlier_threshold).collect();
    let warning = inlier_warning("sc2pcr", &pts, &inliers);
    let ranked = (top_n > 0).then(|| {
        // (seed position, consensus) by the rule above: the winner `best` comes first
        let mut top = TopN::new(top_n);
        let better = |a: &(usize, usize), b: &(usize, usize)| a.1 > b.1 || a.1 == b.1 && a.0 < b.0;
        for (k, h) in hyps.iter().enumerate() {
            if h.is_some() {
                top.push((k, fitness[k]), better);
            }
        }
        Hypotheses {
            estimator: "sc2pcr".into(),
            rule: format!(
                "consensus size: correspondences within {:.3} m under the seed's pose, ties to \
                 the earlier seed; the best is post-refined ({} iterations) into the estimate",
                p.inlier_threshold, p.refine_iterations
            ),
            threshold_m: p.inlier_threshold as f64,
            total: hyps.iter().filter(|h| h.is_some()).count(),
            list: top
                .into_vec()
                .into_iter()
                .enumerate()
                .map(|(r, (k, f))| {
                    let pose = hyps[k].unwrap_or_else(Isometry3::identity);
                    let d = pts.residuals(&pose);
                    Hypothesis {
                        rank: r + 1,
                        sample: vec![seeds[k]],
                        consensus: f,
                        sse: None,
                        pose,
                        inliers: (0..n).filter(|&i| d[i] < p.inlier_threshold).collect(),
                        winner: k == best,
                    }
                })
                .collect(),
            refined: trans,
        }
    });
    Ok((
        Estimate {
            target_from_source: trans,
            inliers,
            method: "sc2pcr".into(),
            warning,
        },
        ranked,
    ))
}

/// A warning when the inlier set cannot pin down a pose: fewer than 3, or identical or
/// collinear source or target points.
pub(crate) fn inlier_warning(who: &str, p: &Soa, inliers: &[usize]) -> Option<String> {
    if inliers.len() < 3 {
        return Some(format!(
            "{who}: only {} of {} correspondences agree with the estimate",
            inliers.len(),
            p.n
        ));
    }
    for (name, f) in [
        ("source", Soa::src64 as fn(&Soa, usize) -> Vector3<f64>),
        ("target", Soa::tgt64),
    ] {
        if let Some(what) = kabsch::spread_problem(inliers.len(), |k| (f(p, inliers[k]), 1.0)) {
            return Some(format!(
                "{who}: the {} inlier {name} points are {what}; the pose is not determined",
                inliers.len()
            ));
        }
    }
    None
}

/// Correspondence endpoints as structure-of-arrays f32, for vectorised distance loops.
pub(crate) struct Soa {
    pub n: usize,
    sx: Vec<f32>,
    sy: Vec<f32>,
    sz: Vec<f32>,
    tx: Vec<f32>,
    ty: Vec<f32>,
    tz: Vec<f32>,
}

impl Soa {
    pub fn new(src: &[Point3<f32>], tgt: &[Point3<f32>]) -> Self {
        Soa {
            n: src.len(),
            sx: src.iter().map(|p| p.x).collect(),
            sy: src.iter().map(|p| p.y).collect(),
            sz: src.iter().map(|p| p.z).collect(),
            tx: tgt.iter().map(|p| p.x).collect(),
            ty: tgt.iter().map(|p| p.y).collect(),
            tz: tgt.iter().map(|p| p.z).collect(),
        }
    }
    pub fn src64(&self, i: usize) -> Vector3<f64> {
        Vector3::new(self.sx[i] as f64, self.sy[i] as f64, self.sz[i] as f64)
    }
    pub fn tgt64(&self, i: usize) -> Vector3<f64> {
        Vector3::new(self.tx[i] as f64, self.ty[i] as f64, self.tz[i] as f64)
    }
    /// `(Ds, C)` for the pair (i, j): the one formula used everywhere, so that bitsets and
    /// recomputed local matrices agree bit for bit.
    #[inline(always)]
    pub fn cross(&self, i: usize, j: usize) -> (f32, f32) {
        let (dx, dy, dz) = (
            self.sx[i] - self.sx[j],
            self.sy[i] - self.sy[j],
            self.sz[i] - self.sz[j],
        );
        let ds = (dx * dx + dy * dy + dz * dz).sqrt();
        let (ex, ey, ez) = (
            self.tx[i] - self.tx[j],
            self.ty[i] - self.ty[j],
            self.tz[i] - self.tz[j],
        );
        let dt = (ex * ex + ey * ey + ez * ez).sqrt();
        (ds, (ds - dt).abs())
    }
    /// `‖R p_i + t − q_i‖` in f32 for every correspondence.
    pub fn residuals(&self, t: &Isometry3<f64>) -> Vec<f32> {
        let (r, tr) = rt32(t);
        (0..self.n)
            .map(|i| residual(&r, &tr, self, i))
            .collect::<Vec<f32>>()
    }
    pub fn count_inliers(&self, t: &Isometry3<f64>, thr: f32) -> usize {
        let (r, t) = rt32(t);
        let n = self.n;
        // Over slices (no bounds checks) so that it vectorises; same arithmetic as `residual`.
        let (sx, sy, sz) = (&self.sx[..n], &self.sy[..n], &self.sz[..n]);
        let (tx, ty, tz) = (&self.tx[..n], &self.ty[..n], &self.tz[..n]);
        let mut c = 0u32;
        for i in 0..n {
            let (x, y, z) = (sx[i], sy[i], sz[i]);
            let dx = r[0] * x + r[1] * y + r[2] * z + t[0] - tx[i];
            let dy = r[3] * x + r[4] * y + r[5] * z + t[1] - ty[i];
            let dz = r[6] * x + r[7] * y + r[8] * z + t[2] - tz[i];
            c += ((dx * dx + dy * dy + dz * dz).sqrt() < thr) as u32;
        }
        c as usize
    }
}

fn rt32(t: &Isometry3<f64>) -> ([f32; 9], [f32; 3]) {
    let m = t.rotation.to_rotation_matrix().into_inner();
    let mut r = [0f32; 9];
    for a in 0..3 {
        for b in 0..3 {
            r[a * 3 + b] = m[(a, b)] as f32;
        }
    }
    let v = t.translation.vector;
    (r, [v.x as f32, v.y as f32, v.z as f32])
}

#[inline(always)]
fn residual(r: &[f32; 9], t: &[f32; 3], p: &Soa, i: usize) -> f32 {
    let (x, y, z) = (p.sx[i], p.sy[i], p.sz[i]);
    let dx = r[0] * x + r[1] * y + r[2] * z + t[0] - p.tx[i];
    let dy = r[3] * x + r[4] * y + r[5] * z + t[1] - p.ty[i];
    let dz = r[6] * x + r[7] * y + r[8] * z + t[2] - p.tz[i];
    (dx * dx + dy * dy + dz * dz).sqrt()
}

/// The compatibility graph: `hard`, `tight` and `near` bitsets (n rows of `stride` u64 each,
/// so that the tight rows scanned by SC2 are contiguous) and SC values.
pub(crate) struct Graph {
    pub n: usize,
    /// u64 words per bitset row: ceil(n / 64) rounded up to a multiple of 8, zero-padded.
    stride: usize,
    hard: Vec<u64>,
    tight: Vec<u64>,
    near: Vec<u64>,
    /// The upper triangle of SC in compressed rows: row i holds (column j > i, SC value) for
    /// every set bit of `hard[i]` with j > i, ascending.
    sc_start: Vec<usize>,
    sc_col: Vec<u32>,
    sc_val: Vec<f32>,
    /// Row ranges of the matvec's fixed partition (fixed so the f32 sums are deterministic).
    parts: Vec<(usize, usize)>,
    isa: Isa,
    /// `|tight[i]|`, an upper bound of every SC2 value in row or column i.
    tight_count: Vec<u32>,
    /// Rows with `|tight[i]| > 0` by decreasing `|tight[i]|`, ties by index.
    by_tight: Vec<u32>,
}

/// Computes words `w0..words` of row i (columns `64 w0..n`) of the three bitsets, and the SC
/// values of the set `hard` bits with column > i (the upper triangle; SC is symmetric).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn build_row(
    p: &Soa,
    i: usize,
    d: f32,
    nms: f32,
    w0: usize,
    words: usize,
    (hard, tight, near): (&mut [u64], &mut [u64], &mut [u64]),
    vals: &mut Vec<(u32, f32)>,
) {
    let half = d / 2.0;
    let d2 = d * d;
    let mut c = [0f32; 64];
    let mut ds = [0f32; 64];
    let (xi, yi, zi) = (p.sx[i], p.sy[i], p.sz[i]);
    let (ui, vi, wi) = (p.tx[i], p.ty[i], p.tz[i]);
    for w in w0..words {
        let base = w * 64;
        let len = (p.n - base).min(64);
        // Same arithmetic as `Soa::cross`, over slices so that it vectorises.
        let r = base..base + len;
        let (sx, sy, sz) = (&p.sx[r.clone()], &p.sy[r.clone()], &p.sz[r.clone()]);
        let (tx, ty, tz) = (&p.tx[r.clone()], &p.ty[r.clone()], &p.tz[r]);
        for k in 0..len {
            let (dx, dy, dz) = (xi - sx[k], yi - sy[k], zi - sz[k]);
            let a = (dx * dx + dy * dy + dz * dz).sqrt();
            let (ex, ey, ez) = (ui - tx[k], vi - ty[k], wi - tz[k]);
            let b = (ex * ex + ey * ey + ez * ez).sqrt();
            ds[k] = a;
            c[k] = (a - b).abs();
        }
        let (mut h, mut t, mut r) = (0u64, 0u64, 0u64);
        for k in 0..len {
            h |= ((c[k] < d) as u64) << k;
            t |= ((c[k] < half) as u64) << k;
            r |= ((ds[k] < nms) as u64) << k;
        }
        hard[w] = h;
        tight[w] = t;
        near[w] = r;
        // Upper triangle only: columns > i.
        let mut m = if w == i / 64 {
            h & (u64::MAX << (i % 64)) & !(1u64 << (i % 64))
        } else {
            h
        };
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            vals.push(((base + k) as u32, (1.0 - c[k] * c[k] / d2).max(0.0)));
            m &= m - 1;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn build_row_avx2(
    p: &Soa,
    i: usize,
    d: f32,
    nms: f32,
    w0: usize,
    words: usize,
    rows: (&mut [u64], &mut [u64], &mut [u64]),
    vals: &mut Vec<(u32, f32)>,
) {
    build_row(p, i, d, nms, w0, words, rows, vals)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn build_row_avx512(
    p: &Soa,
    i: usize,
    d: f32,
    nms: f32,
    w0: usize,
    words: usize,
    rows: (&mut [u64], &mut [u64], &mut [u64]),
    vals: &mut Vec<(u32, f32)>,
) {
    build_row(p, i, d, nms, w0, words, rows, vals)
}

/// In-place transpose of a 64 x 64 bit matrix: bit c of `a[r]` becomes bit r of `a[c]`.
fn transpose64(a: &mut [u64; 64]) {
    let mut j = 32usize;
    let mut m: u64 = 0x0000_0000_FFFF_FFFF;
    while j != 0 {
        let mut k = 0usize;
        while k < 64 {
            // Swap the high j bits of a[k] with the low j bits of a[k + j], per j-block.
            let t = ((a[k] >> j) ^ a[k | j]) & m;
            a[k] ^= t << j;
            a[k | j] ^= t;
            k = ((k | j) + 1) & !j;
        }
        j >>= 1;
        m ^= m << j;
    }
}

/// A raw pointer that may cross threads; every use documents why its accesses are disjoint.
#[derive(Clone, Copy)]
struct SharedMut(*mut u64);
// SAFETY: only used for disjoint writes/reads described at the use site.
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

/// Indices of the set bits of a row, ascending.
#[inline]
fn for_each_bit(row: &[u64], mut f: impl FnMut(usize)) {
    for (w, &word) in row.iter().enumerate() {
        let mut m = word;
        while m != 0 {
            f(w * 64 + m.trailing_zeros() as usize);
            m &= m - 1;
        }
    }
}

#[inline]
fn bit(row: &[u64], j: usize) -> bool {
    row[j / 64] >> (j % 64) & 1 == 1
}

/// torch.allclose defaults: |a − b| ≤ 1e-8 + 1e-5 |b|.
fn allclose(a: &[f32], b: &[f32]) -> bool {
    a.iter()
        .zip(b)
        .all(|(&x, &y)| (x - y).abs() <= 1e-8 + 1e-5 * y.abs())
}

/// `v / (‖v‖ + 1e-6)`.
fn normalise(v: &mut [f32]) {
    let norm = v
        .iter()
        .map(|&x| (x as f64) * (x as f64))
        .sum::<f64>()
        .sqrt() as f32;
    let s = norm + 1e-6;
    for x in v {
        *x /= s;
    }
}

impl Graph {
    pub fn build(p: &Soa, d: f32, nms: f32) -> Graph {
        let n = p.n;
        let words = n.div_ceil(64);
        // Rows padded to whole 512-bit vectors (the padding stays 0).
        let stride = words.div_ceil(8) * 8;
        let mut hard = vec![0u64; n * stride];
        let mut tight = vec![0u64; n * stride];
        let mut near = vec![0u64; n * stride];
        let isa = crate::simd::features().bitset_isa();
        // Pass 1: the diagonal 64-column block and everything right of it (all three relations
        // are symmetric: `cross(i, j)` and `cross(j, i)` are bit-identical).
        let rows: Vec<Vec<(u32, f32)>> = hard
            .par_chunks_mut(stride)
            .zip(tight.par_chunks_mut(stride))
            .zip(near.par_chunks_mut(stride))
            .enumerate()
            .map(|(i, ((h, t), r))| {
                let row = (h, t, r);
                let w0 = i / 64;
                let mut vals = Vec::with_capacity((n - i) / 8 + 16);
                match isa {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: the CPU supports these features (checked by `bitset_isa`).
                    Isa::Avx512 => unsafe {
                        build_row_avx512(p, i, d, nms, w0, words, row, &mut vals)
                    },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: as above.
                    Isa::Avx2 => unsafe { build_row_avx2(p, i, d, nms, w0, words, row, &mut vals) },
                    _ => build_row(p, i, d, nms, w0, words, row, &mut vals),
                }
                vals
            })
            .collect();
        // Pass 2: the words left of the diagonal block, as 64 x 64 bit transposes of pass 1's.
        let blocks = words;
        let ptrs = [
            SharedMut(hard.as_mut_ptr()),
            SharedMut(tight.as_mut_ptr()),
            SharedMut(near.as_mut_ptr()),
        ];
        (1..blocks).into_par_iter().for_each(|bi| {
            let rows_i = (n - bi * 64).min(64);
            let mut tile = [0u64; 64];
            for ptr in ptrs {
                for bj in 0..bi {
                    // Block bj < bi is full (64 rows). Reads: word bi of rows in block bj,
                    // written by pass 1 only. Writes: word bj < bi of rows in block bi, which
                    // only this task touches and no task reads.
                    for (a, t) in tile.iter_mut().enumerate() {
                        // SAFETY: (bj * 64 + a) < n and bi < words: in bounds; see above.
                        *t = unsafe { *ptr.0.add((bj * 64 + a) * stride + bi) };
                    }
                    transpose64(&mut tile);
                    for (b, &t) in tile.iter().enumerate().take(rows_i) {
                        // SAFETY: (bi * 64 + b) < n and bj < words: in bounds; see above.
                        unsafe { *ptr.0.add((bi * 64 + b) * stride + bj) = t };
                    }
                }
            }
        });
        let tight_count: Vec<u32> = tight
            .chunks(stride)
            .map(|r| r.iter().map(|w| w.count_ones()).sum())
            .collect();
        let mut by_tight: Vec<u32> = (0..n as u32)
            .filter(|&j| tight_count[j as usize] > 0)
            .collect();
        by_tight.sort_unstable_by(|&a, &b| {
            tight_count[b as usize]
                .cmp(&tight_count[a as usize])
                .then(a.cmp(&b))
        });
        let mut sc_start = Vec::with_capacity(n + 1);
        sc_start.push(0);
        for r in &rows {
            sc_start.push(sc_start[sc_start.len() - 1] + r.len());
        }
        let nnz = sc_start[n];
        let mut sc_col = Vec::with_capacity(nnz);
        let mut sc_val = Vec::with_capacity(nnz);
        for r in rows {
            for (j, v) in r {
                sc_col.push(j);
                sc_val.push(v);
            }
        }
        // About equal work per part: each entry is read once (gather) and written once
        // (scatter), each row also costs a little.
        const PARTS: usize = 16;
        let cost = |i: usize| sc_start[i] + 8 * i;
        let total = cost(n);
        let mut parts = Vec::with_capacity(PARTS);
        let mut lo = 0;
        for k in 1..=PARTS {
            let want = total * k / PARTS;
            let mut hi = lo;
            while hi < n && cost(hi) < want {
                hi += 1;
            }
            if k == PARTS {
                hi = n;
            }
            if hi > lo {
                parts.push((lo, hi));
            }
            lo = hi;
        }
        Graph {
            n,
            stride,
            hard,
            tight,
            near,
            sc_start,
            sc_col,
            sc_val,
            parts,
            isa,
            tight_count,
            by_tight,
        }
    }

    pub fn hard(&self, i: usize) -> &[u64] {
        &self.hard[i * self.stride..(i + 1) * self.stride]
    }
    pub fn tight(&self, i: usize) -> &[u64] {
        &self.tight[i * self.stride..(i + 1) * self.stride]
    }
    pub fn near(&self, i: usize) -> &[u64] {
        &self.near[i * self.stride..(i + 1) * self.stride]
    }

    /// `y = SC x`, from the upper triangle: each part of rows gathers `SC[i, j>i] x_j` and
    /// scatters `SC[i, j] x_i` into its own buffer; buffers are summed in a fixed order.
    fn matvec(&self, x: &[f32], y: &mut [f32]) {
        let n = self.n;
        let partial: Vec<Vec<f32>> = self
            .parts
            .par_iter()
            .map(|&(lo, hi)| {
                let mut yl = vec![0f32; n];
                for i in lo..hi {
                    let r = self.sc_start[i]..self.sc_start[i + 1];
                    let (cols, vals) = (&self.sc_col[r.clone()], &self.sc_val[r]);
                    let xi = x[i];
                    let mut acc = [0f32; 4];
                    let (cc, vc) = (cols.chunks_exact(4), vals.chunks_exact(4));
                    let (cr, vr) = (cc.remainder(), vc.remainder());
                    for (c, v) in cc.zip(vc) {
                        for l in 0..4 {
                            let j = c[l] as usize;
                            acc[l] += v[l] * x[j];
                            yl[j] += v[l] * xi;
                        }
                    }
                    for (&j, &v) in cr.iter().zip(vr) {
                        acc[0] += v * x[j as usize];
                        yl[j as usize] += v * xi;
                    }
                    yl[i] += (acc[0] + acc[1]) + (acc[2] + acc[3]);
                }
                yl
            })
            .collect();
        y.par_chunks_mut(1024).enumerate().for_each(|(c, ys)| {
            let base = c * 1024;
            for (k, yv) in ys.iter_mut().enumerate() {
                *yv = partial.iter().map(|p| p[base + k]).sum();
            }
        });
    }

    /// Leading eigenvector of SC by power iteration from ones (reference
    /// `cal_leading_eigenvector`: normalise by ‖v‖ + 1e-6, stop early on allclose).
    pub fn leading_eigenvector(&self, iterations: usize) -> Vec<f32> {
        let mut v = vec![1f32; self.n];
        let mut y = vec![0f32; self.n];
        for _ in 0..iterations {
            self.matvec(&v, &mut y);
            normalise(&mut y);
            let done = allclose(&y, &v);
            std::mem::swap(&mut v, &mut y);
            if done {
                break;
            }
        }
        v
    }

    /// NMS seeds: i is a local maximum when conf_i ≥ conf_j for every j with Ds_ij < R; the
    /// values conf·is_local_max are sorted descending (stable) and the first `num` taken, so
    /// zeros (non-maxima) fill the list when there are too few maxima.
    pub fn pick_seeds(&self, conf: &[f32], num: usize) -> Vec<usize> {
        let score: Vec<f32> = (0..self.n)
            .into_par_iter()
            .map(|i| {
                let mut local_max = true;
                for_each_bit(self.near(i), |j| local_max &= conf[i] >= conf[j]);
                if local_max {
                    conf[i]
                } else {
                    0.0
                }
            })
            .collect();
        let mut order: Vec<usize> = (0..self.n).collect();
        order.sort_by(|&a, &b| score[b].total_cmp(&score[a]));
        order.truncate(num);
        order
    }

    /// Top-k1 correspondences of seed s by `SC2[s, j] = |tight[s] ∩ tight[j]| · hard[s, j]`,
    /// descending, ties by lower index; zero-valued entries fill the list in index order.
    #[cfg(test)]
    pub fn sc2_top_k(&self, s: usize, k1: usize) -> Vec<usize> {
        self.sc2_top_k_block(&[s], k1).pop().unwrap_or_default()
    }

    /// [`sc2_top_k`](Self::sc2_top_k) for a block of seeds at once. Candidates j are visited
    /// in the global order of decreasing `|tight[j]|` (ties by index), so for every seed the
    /// bound `min(|tight[j]|, |tight[s]|)` never increases and its scan stops once nothing left
    /// can enter its top-k1; the result does not depend on the visiting order. Each tight row
    /// is loaded once per block instead of once per seed.
    pub fn sc2_top_k_block(&self, seeds: &[usize], k1: usize) -> Vec<Vec<usize>> {
        let tc = &self.tight_count;
        // (value, index) ordered by value desc, then index asc.
        let mut tops: Vec<Vec<(u32, usize)>> = vec![Vec::with_capacity(k1 + 1); seeds.len()];
        let mut active: Vec<bool> = seeds.iter().map(|&s| tc[s] > 0).collect();
        let mut need: Vec<usize> = Vec::with_capacity(seeds.len());
        let mut rows: Vec<&[u64]> = Vec::with_capacity(seeds.len());
        let mut vals = vec![0u32; seeds.len()];
        for &j in &self.by_tight {
            let j = j as usize;
            let tj = self.tight(j);
            let mut any = false;
            need.clear();
            rows.clear();
            for (b, &s) in seeds.iter().enumerate() {
                if !active[b] {
                    continue;
                }
                let top = &tops[b];
                let bound = tc[j].min(tc[s]);
                if top.len() == k1 && bound < top[k1 - 1].0 {
                    active[b] = false;
                    continue;
                }
                any = true;
                if bit(self.hard(s), j) {
                    need.push(b);
                    rows.push(self.tight(s));
                }
            }
            if !any {
                break;
            }
            let vals = &mut vals[..need.len()];
            match self.isa {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: the CPU supports AVX-512F and VPOPCNTDQ (checked by `bitset_isa`);
                // rows are `stride` words, a multiple of 8.
                Isa::Avx512 => unsafe {
                    crate::simd::x86_64_avx512::and_popcount_many(tj, &rows, vals)
                },
                _ => {
                    for (v, r) in vals.iter_mut().zip(&rows) {
                        *v = crate::simd::and_popcount(self.isa, r, tj);
                    }
                }
            }
            for (&b, &v) in need.iter().zip(vals.iter()) {
                if v == 0 {
                    continue;
                }
                let top = &mut tops[b];
                let pos = top.partition_point(|&(tv, tl)| tv > v || (tv == v && tl < j));
                if pos < k1 {
                    top.insert(pos, (v, j));
                    top.truncate(k1);
                }
            }
        }
        tops.into_iter()
            .map(|top| {
                let mut knn: Vec<usize> = top.iter().map(|&(_, j)| j).collect();
                if knn.len() < k1 {
                    let mut chosen = knn.clone();
                    chosen.sort_unstable();
                    for j in 0..self.n {
                        if knn.len() == k1 {
                            break;
                        }
                        if chosen.binary_search(&j).is_err() {
                            knn.push(j);
                        }
                    }
                }
                knn
            })
            .collect()
    }

    /// Second stage: within the k1 set, row 0 of `hard @ hard` (local hard from the global
    /// bitset, which uses the same distance formula), top-k2 descending, stable.
    pub fn second_stage(&self, knn: &[usize], k2: usize) -> Vec<usize> {
        let h0 = self.hard(knn[0]);
        let score: Vec<u32> = knn
            .iter()
            .map(|&m| {
                knn.iter()
                    .filter(|&&l| bit(h0, l) && bit(self.hard(l), m))
                    .count() as u32
            })
            .collect();
        let mut order: Vec<usize> = (0..knn.len()).collect();
        order.sort_by(|&a, &b| score[b].cmp(&score[a]));
        order.truncate(k2);
        order.into_iter().map(|k| knn[k]).collect()
    }
}

/// Per-seed weights: leading eigenvector of `M = clamp(1 − C²/d², 0)` with zero diagonal over
/// the k2 set, normalised to sum 1 (+1e-6). The reference runs all seeds as one batch, so its
/// early stop (allclose) fires only when every seed has converged; that is reproduced here.
pub(crate) fn seed_weights(
    p: &Soa,
    sets: &[Vec<usize>],
    d: f32,
    iterations: usize,
) -> Vec<Vec<f32>> {
    let d2 = d * d;
    // Per seed: the iterates and whether each was allclose to its predecessor.
    let hist: Vec<(Vec<Vec<f32>>, Vec<bool>)> = sets
        .par_iter()
        .map(|set| {
            let k = set.len();
            let mut m = vec![0f32; k * k];
            for a in 0..k {
                for b in 0..k {
                    if a != b {
                        let (_, c) = p.cross(set[a], set[b]);
                        m[a * k + b] = (1.0 - c * c / d2).max(0.0);
                    }
                }
            }
            let mut v = vec![1f32; k];
            let mut iters = Vec::with_capacity(iterations);
            let mut close = Vec::with_capacity(iterations);
            for _ in 0..iterations {
                let mut y: Vec<f32> = (0..k)
                    .map(|a| (0..k).map(|b| m[a * k + b] * v[b]).sum())
                    .collect();
                normalise(&mut y);
                close.push(allclose(&y, &v));
                v = y.clone();
                iters.push(y);
            }
            (iters, close)
        })
        .collect();
    let last = iterations.saturating_sub(1);
    let stop = (0..iterations)
        .find(|&t| hist.iter().all(|(_, c)| c[t]))
        .unwrap_or(last);
    hist.into_iter()
        .zip(sets)
        .map(|((iters, _), set)| {
            let mut w = iters
                .get(stop)
                .cloned()
                .unwrap_or_else(|| vec![1f32; set.len()]);
            let s: f32 = w.iter().sum::<f32>() + 1e-6;
            for x in &mut w {
                *x /= s;
            }
            w
        })
        .collect()
}

/// Reference `post_refinement`: re-solve on the inliers with weights 1/(1 + (d/thr)²) until the
/// inlier count stops changing, at most `iterations` times.
fn post_refinement(
    p: &Soa,
    mut trans: Isometry3<f64>,
    thr: f32,
    iterations: usize,
) -> Isometry3<f64> {
    let mut previous = 0usize;
    for _ in 0..iterations {
        let d = p.residuals(&trans);
        let inl: Vec<usize> = (0..p.n).filter(|&i| d[i] < thr).collect();
        if inl.len() == previous || inl.len() < 3 {
            break;
        }
        previous = inl.len();
        let w = |i: usize| 1.0 / (1.0 + ((d[i] / thr) as f64).powi(2));
        match kabsch::solve(
            inl.len(),
            |k| (p.src64(inl[k]), p.tgt64(inl[k]), w(inl[k])),
            1e-6,
        ) {
            Some(t) => trans = t,
            None => break,
        }
    }
    trans
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::synthetic::synthetic_correspondences;
    use crate::metrics::{rre_deg, rte_m};

    /// The reference's dense NumPy/torch formulation, written out naively.
    struct Dense {
        n: usize,
        c: Vec<f32>,
        ds: Vec<f32>,
    }

    impl Dense {
        fn new(p: &Soa) -> Dense {
            let n = p.n;
            let mut c = vec![0f32; n * n];
            let mut ds = vec![0f32; n * n];
            for i in 0..n {
                for j in 0..n {
                    let (a, b) = p.cross(i, j);
                    ds[i * n + j] = a;
                    c[i * n + j] = b;
                }
            }
            Dense { n, c, ds }
        }
        fn eig(&self, d: f32, iters: usize) -> Vec<f32> {
            let n = self.n;
            let sc: Vec<f32> = self
                .c
                .iter()
                .map(|&c| (1.0 - c * c / (d * d)).max(0.0))
                .collect();
            let mut v = vec![1f32; n];
            for _ in 0..iters {
                let mut y: Vec<f32> = (0..n)
                    .map(|i| {
                        (0..n)
                            .map(|j| (sc[i * n + j] as f64) * (v[j] as f64))
                            .sum::<f64>() as f32
                    })
                    .collect();
                normalise(&mut y);
                let done = allclose(&y, &v);
                v = y;
                if done {
                    break;
                }
            }
            v
        }
        fn seeds(&self, conf: &[f32], r: f32, num: usize) -> Vec<usize> {
            let n = self.n;
            let score: Vec<f32> = (0..n)
                .map(|i| {
                    let lm = (0..n).all(|j| conf[i] >= conf[j] || self.ds[i * n + j] >= r);
                    conf[i] * (lm as u8 as f32)
                })
                .collect();
            let mut o: Vec<usize> = (0..n).collect();
            o.sort_by(|&a, &b| score[b].total_cmp(&score[a]));
            o.truncate(num);
            o
        }
        fn knn(&self, seed: usize, d: f32, k1: usize, k2: usize) -> Vec<usize> {
            let n = self.n;
            let hard = |i: usize, j: usize| (self.c[i * n + j] < d) as u32;
            let tight = |i: usize, j: usize| (self.c[i * n + j] < d / 2.0) as u32;
            let sc2: Vec<u32> = (0..n)
                .map(|j| (0..n).map(|l| tight(seed, l) * tight(l, j)).sum::<u32>() * hard(seed, j))
                .collect();
            let mut o: Vec<usize> = (0..n).collect();
            o.sort_by(|&a, &b| sc2[b].cmp(&sc2[a]));
            let knn: Vec<usize> = o[..k1].to_vec();
            let row0: Vec<u32> = (0..k1)
                .map(|m| {
                    (0..k1)
                        .map(|l| hard(knn[0], knn[l]) * hard(knn[l], knn[m]))
                        .sum()
                })
                .collect();
            let mut o2: Vec<usize> = (0..k1).collect();
            o2.sort_by(|&a, &b| row0[b].cmp(&row0[a]));
            o2[..k2].iter().map(|&k| knn[k]).collect()
        }
    }

    #[test]
    fn transpose64_matches_naive() {
        let mut s = 0x1234_5678_9abc_def0u64;
        let mut a = [0u64; 64];
        for w in &mut a {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            *w = s;
        }
        let mut t = a;
        transpose64(&mut t);
        for (r, ar) in a.iter().enumerate() {
            for (c, tc) in t.iter().enumerate() {
                assert_eq!(tc >> r & 1, ar >> c & 1, "({r}, {c})");
            }
        }
    }

    #[test]
    fn popcount_kernels_agree() {
        use crate::simd::{and_popcount, features, scalar};
        let a: Vec<u64> = (0..131u64)
            .map(|k| k.wrapping_mul(0x9e37_79b9_7f4a_7c15))
            .collect();
        let b: Vec<u64> = (0..131u64)
            .map(|k| (k + 7).wrapping_mul(0xc2b2_ae3d_27d4_eb4f))
            .collect();
        let want = scalar::and_popcount(&a, &b);
        for isa in [Isa::Scalar, features().bitset_isa()] {
            assert_eq!(and_popcount(isa, &a, &b), want);
        }
        #[cfg(target_arch = "x86_64")]
        if features().bitset_isa() == Isa::Avx512 {
            let pad = |v: &[u64]| {
                let mut p = v.to_vec();
                p.resize(136, 0);
                p
            };
            let rows: Vec<Vec<u64>> = (0..6u64)
                .map(|r| {
                    pad(&b
                        .iter()
                        .map(|x| x.rotate_left(r as u32 * 7))
                        .collect::<Vec<_>>())
                })
                .collect();
            let refs: Vec<&[u64]> = rows.iter().map(|r| r.as_slice()).collect();
            let mut out = vec![0u32; 6];
            // SAFETY: checked AVX-512 support; rows are 136 = 17 x 8 words.
            unsafe { crate::simd::x86_64_avx512::and_popcount_many(&pad(&a), &refs, &mut out) };
            for (o, r) in out.iter().zip(&rows) {
                assert_eq!(*o, scalar::and_popcount(&pad(&a), r));
            }
        }
    }

    #[test]
    fn bitset_graph_matches_dense_transcription() {
        let data = synthetic_correspondences(400, 300, 0.3, 0.01, 11);
        let p = Soa::new(&data.src, &data.tgt);
        let prm = Sc2PcrParams::default();
        let g = Graph::build(&p, prm.d_thre, prm.nms_radius);
        let dense = Dense::new(&p);
        let n = p.n;
        for i in 0..n {
            for j in 0..n {
                let c = dense.c[i * n + j];
                assert_eq!(bit(g.hard(i), j), c < 0.1);
                assert_eq!(bit(g.tight(i), j), c < 0.05);
                assert_eq!(bit(g.near(i), j), dense.ds[i * n + j] < 0.1);
            }
        }
        let conf = g.leading_eigenvector(prm.num_iterations);
        let conf_d = dense.eig(prm.d_thre, prm.num_iterations);
        for i in 0..n {
            assert!(
                (conf[i] - conf_d[i]).abs() <= 1e-5 * conf_d[i].abs().max(1e-3),
                "eigenvector {i}: {} vs {}",
                conf[i],
                conf_d[i]
            );
        }
        let seeds = g.pick_seeds(&conf, 60);
        assert_eq!(seeds, dense.seeds(&conf_d, prm.nms_radius, 60));
        for &s in &seeds {
            let knn = g.sc2_top_k(s, prm.k1);
            assert_eq!(knn.len(), prm.k1);
            assert_eq!(
                g.second_stage(&knn, prm.k2),
                dense.knn(s, prm.d_thre, prm.k1, prm.k2),
                "seed {s}"
            );
        }
        // The leading eigenvector favours true matches.
        let mean = |f: bool| {
            let v: Vec<f32> = (0..n)
                .filter(|&i| data.is_inlier[i] == f)
                .map(|i| conf[i])
                .collect();
            v.iter().sum::<f32>() / v.len() as f32
        };
        assert!(mean(true) > 3.0 * mean(false));
    }

    fn check_recovers(ratio: f64, seed: u64) {
        let data = synthetic_correspondences(2000, 2000, ratio, 0.01, seed);
        let est = sc2pcr(&data.src, &data.tgt, &Sc2PcrParams::default()).unwrap();
        let gt = data.target_from_source;
        let (rre, rte) = (
            rre_deg(&est.target_from_source, &gt),
            rte_m(&est.target_from_source, &gt),
        );
        assert!(
            rre < 2.0 && rte < 0.05,
            "ratio {ratio}: rre {rre} rte {rte}"
        );
        let true_in = est.inliers.iter().filter(|&&i| data.is_inlier[i]).count();
        let n_true = data.is_inlier.iter().filter(|&&b| b).count();
        assert!(
            true_in as f64 >= 0.9 * est.inliers.len() as f64,
            "{true_in} of {}",
            est.inliers.len()
        );
        assert!(
            true_in as f64 >= 0.95 * n_true as f64,
            "{true_in} of {n_true}"
        );
        assert_eq!(est.method, "sc2pcr");
        assert!(est.warning.is_none());
    }

    #[test]
    fn recovers_pose_at_30_percent_inliers() {
        check_recovers(0.3, 21);
    }

    #[test]
    fn recovers_pose_at_10_percent_inliers() {
        check_recovers(0.1, 22);
    }

    #[test]
    fn too_few_or_bad_input_is_an_error() {
        let data = synthetic_correspondences(100, 4, 1.0, 0.0, 3);
        assert!(sc2pcr(&data.src, &data.tgt, &Sc2PcrParams::default()).is_err());
        let data = synthetic_correspondences(100, 50, 1.0, 0.0, 3);
        assert!(sc2pcr(&data.src, &data.tgt[..49], &Sc2PcrParams::default()).is_err());
        let mut src = data.src.clone();
        src[7].x = f32::NAN;
        assert!(sc2pcr(&src, &data.tgt, &Sc2PcrParams::default()).is_err());
        // Small but valid: k1 falls back to 4.
        let data = synthetic_correspondences(100, 20, 1.0, 0.0, 4);
        let est = sc2pcr(&data.src, &data.tgt, &Sc2PcrParams::default()).unwrap();
        assert!(rre_deg(&est.target_from_source, &data.target_from_source) < 1e-2);
        // Identical points do not panic.
        let same = vec![Point3::new(1.0f32, 2.0, 3.0); 50];
        let _ = sc2pcr(&same, &same, &Sc2PcrParams::default());
    }

    #[test]
    fn max_points_keeps_the_first_correspondences() {
        let data = synthetic_correspondences(500, 600, 0.5, 0.005, 5);
        let prm = Sc2PcrParams {
            max_points: 300,
            ..Default::default()
        };
        let est = sc2pcr(&data.src, &data.tgt, &prm).unwrap();
        assert!(est.inliers.iter().all(|&i| i < 300));
        let est2 = sc2pcr(&data.src[..300], &data.tgt[..300], &prm).unwrap();
        assert_eq!(est.inliers, est2.inliers);
        assert_eq!(est.target_from_source, est2.target_from_source);
    }
}
