//! The paper's default configuration (row softmax per branch, stable Noisy-AND, mutual or
//! row nearest neighbours) in one pass over the rows instead of five passes over N x M
//! matrices: per row, both softmaxes are written, the Noisy-AND rank keys are formed in a
//! row-sized scratch buffer, the row argmax and the running column maxima are updated, and
//! the fused posteriors are written. The outputs are bit-identical to the general path
//! (`calibrate` x 2, `noisy_and_rank_keys`, `select`, `rank_keys_to_posteriors`): the same
//! per-element formulas, the same per-row reductions, and the same tie rules (row ties to the
//! lowest column, column ties to the lowest row).

use super::calibrate::{fast_exp, max_lanes, sum_lanes};
use super::fuse::{default_prior, noisy_and_rank_key};
use super::select::{order, Selection};
use super::Correspondence;
use crate::matrix::{rows_per_task, DenseMatrix};
use crate::simd::Isa;
use crate::{Error, Result};
use rayon::prelude::*;

/// Where a branch's similarity rows come from.
#[derive(Clone, Copy)]
pub(crate) enum Sim<'a> {
    /// A kept N x M matrix.
    Dense(&'a DenseMatrix),
    /// Unit-normalised source and target features (`similarity::normalize_rows`): each band's
    /// rows are formed with `similarity::dot_band` when the band is processed, as
    /// `cosine_similarity` forms them, so no N x M matrix is held.
    Features {
        src: &'a crate::features::Features,
        tgt: &'a super::similarity::DotRhs<'a>,
    },
}

impl Sim<'_> {
    fn shape(&self) -> (usize, usize) {
        match self {
            Sim::Dense(m) => m.shape(),
            Sim::Features { src, tgt } => (src.len(), tgt.len()),
        }
    }
}

/// Row-softmax inputs for one branch: similarity, row validity, column validity.
pub(crate) struct Branch<'a> {
    pub sim: Sim<'a>,
    pub row_valid: Option<&'a [bool]>,
    pub col_valid: Option<&'a [bool]>,
    pub tau: f32,
}

/// The correspondences and, when asked for, the posteriors `(p_img, p_geo, fused)`.
pub(crate) struct FusedOut {
    pub mats: Option<(DenseMatrix, DenseMatrix, DenseMatrix)>,
    pub correspondences: Vec<Correspondence>,
}

fn bias(cols: usize, valid: Option<&[bool]>) -> Vec<f32> {
    match valid {
        Some(c) => c
            .iter()
            .map(|&v| if v { 0.0 } else { f32::NEG_INFINITY })
            .collect(),
        None => vec![0.0; cols],
    }
}

fn check_tau(tau: f32) -> Result<()> {
    if tau.is_finite() && tau > 0.0 {
        Ok(())
    } else {
        Err(Error::Param(format!(
            "calibrate: temperature must be a positive finite number, found {tau}"
        )))
    }
}

/// Per band of rows: column maxima of the rank keys and their rows (`u32::MAX` = none).
type ColBest = (Vec<f32>, Vec<u32>);

struct Ctx<'a> {
    cols: usize,
    band: usize,
    a: &'a Branch<'a>,
    b: &'a Branch<'a>,
    bias_a: &'a [f32],
    bias_b: &'a [f32],
    /// `(1 - pi) / pi`: posterior odds = key * c.
    c: f64,
    want_cols: bool,
    /// Image only: the keys are the first branch's row-softmax posteriors (the second branch
    /// is not read).
    only_a: bool,
    /// Which intrinsics run the row loops (`super::avx2`, `super::avx512`: same bits as the
    /// scalar code; vectorised in every build).
    lanes: Lanes,
}

/// The row kernels' instruction set.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Lanes {
    Scalar,
    Avx2,
    Avx512,
}

/// `out = exp((src + bias - max) * it)`; returns `1 / sum` (the sum as `sum_lanes` forms it),
/// or None when the row is invalid or nothing is finite (the softmax row is then all 0).
/// `out * inv` is bit for bit the row `calibrate`'s row softmax gives.
#[inline(always)]
fn softmax_unnormalised(
    out: &mut [f32],
    src: &[f32],
    bias: &[f32],
    it: f32,
    valid: bool,
    lanes: Lanes,
) -> Option<f32> {
    if !valid {
        return None;
    }
    #[cfg(target_arch = "x86_64")]
    if lanes != Lanes::Scalar {
        // SAFETY: each width is chosen only when the CPU has it (`row_softmax_noisy_and`:
        // `Avx512` needs AVX-512 F/BW/VL/DQ and AVX2).
        let mx = unsafe {
            match lanes {
                Lanes::Avx512 => super::avx512::add_max(out, src, bias),
                _ => super::avx2::add_max(out, src, bias),
            }
        };
        if mx == f32::NEG_INFINITY {
            return None;
        }
        // SAFETY: as above.
        let sum = unsafe {
            match lanes {
                Lanes::Avx512 => super::avx512::exp_sum(out, mx, it),
                _ => super::avx2::exp_sum(out, mx, it),
            }
        };
        return Some(1.0 / sum);
    }
    let _ = lanes;
    for ((o, s), b) in out.iter_mut().zip(src).zip(bias) {
        *o = s + b;
    }
    let mx = max_lanes(out);
    if mx == f32::NEG_INFINITY {
        return None;
    }
    for v in out.iter_mut() {
        *v = fast_exp((*v - mx) * it);
    }
    Some(1.0 / sum_lanes(out))
}

/// First index of `m` in `x` (exact comparison), scanning 64-entry blocks vectorised.
#[inline(always)]
fn first_eq(x: &[f32], m: f32) -> Option<usize> {
    for (q, c) in x.chunks(64).enumerate() {
        let hit = c.iter().fold(false, |h, &v| h | (v == m));
        if hit {
            return c.iter().position(|&v| v == m).map(|k| q * 64 + k);
        }
    }
    None
}

/// Row i: both softmaxes (normalised into `ra`, `rb` when `rf` is given, else left
/// unnormalised there), the rank keys into `keys`, the column maxima updated, the posteriors
/// into `rf` if given; returns the row's best target (first maximum of the keys, if > 0) with
/// its key.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn row_step(
    x: &Ctx<'_>,
    i: usize,
    (sa, sb): (&[f32], &[f32]),
    ra: &mut [f32],
    rb: &mut [f32],
    rf: Option<&mut [f32]>,
    keys: &mut [f32],
    (cb, ci): &mut ColBest,
) -> Option<(usize, f32)> {
    let ok = |v: Option<&[bool]>| v.is_none_or(|r| r[i]);
    if x.only_a {
        // `calibrate`'s row softmax, bit for bit (`out * inv`); an all-0 row selects nothing
        // and cannot beat the column maxima's initial 0.
        let ia = softmax_unnormalised(ra, sa, x.bias_a, 1.0 / x.a.tau, ok(x.a.row_valid), x.lanes)?;
        for (k, &p) in keys.iter_mut().zip(&*ra) {
            *k = p * ia;
        }
        return col_max_and_best(x, i, keys, cb, ci);
    }
    let ia = softmax_unnormalised(ra, sa, x.bias_a, 1.0 / x.a.tau, ok(x.a.row_valid), x.lanes);
    let ib = softmax_unnormalised(rb, sb, x.bias_b, 1.0 / x.b.tau, ok(x.b.row_valid), x.lanes);
    let store = rf.is_some();
    let (ia, ib) = match (ia, ib) {
        (Some(ia), Some(ib)) => (ia, ib),
        _ => {
            // One branch is all 0 in this row: every key and posterior is 0.
            if let Some(rf) = rf {
                for (r, inv) in [(ra, ia), (rb, ib)] {
                    match inv {
                        Some(inv) => r.iter_mut().for_each(|v| *v *= inv),
                        None => r.fill(0.0),
                    }
                }
                rf.fill(0.0);
            }
            return None;
        }
    };
    if store {
        ra.iter_mut().for_each(|v| *v *= ia);
        rb.iter_mut().for_each(|v| *v *= ib);
        for ((k, &p), &q) in keys.iter_mut().zip(&*ra).zip(&*rb) {
            *k = noisy_and_rank_key(p, q);
        }
    } else if cfg!(target_arch = "x86_64") && x.lanes == Lanes::Avx512 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Avx512` is chosen only when the CPU has AVX-512.
        unsafe {
            super::avx512::rank_keys(keys, ra, rb, ia, ib)
        };
    } else if cfg!(target_arch = "x86_64") && x.lanes == Lanes::Avx2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Avx2` is chosen only when the CPU has AVX2.
        unsafe {
            super::avx2::rank_keys(keys, ra, rb, ia, ib)
        };
    } else {
        for ((k, &a), &b) in keys.iter_mut().zip(&*ra).zip(&*rb) {
            *k = noisy_and_rank_key(a * ia, b * ib);
        }
    }
    let best = col_max_and_best(x, i, keys, cb, ci);
    if let Some(rf) = rf {
        for (f, &key) in rf.iter_mut().zip(&*keys) {
            *f = posterior(key, x.c);
        }
    }
    best
}

/// The column maxima updated with row `i`'s keys (when mutual NN needs them), and the row's
/// first maximum key if it is > 0, with the kernels of `x.lanes`.
#[inline(always)]
fn col_max_and_best(
    x: &Ctx<'_>,
    i: usize,
    keys: &[f32],
    cb: &mut [f32],
    ci: &mut [u32],
) -> Option<(usize, f32)> {
    let iu = i as u32;
    #[cfg(target_arch = "x86_64")]
    match x.lanes {
        // SAFETY: each width is chosen only when the CPU has it (`row_softmax_noisy_and`).
        Lanes::Avx512 => unsafe {
            if x.want_cols {
                super::avx512::col_max(keys, cb, ci, iu);
            }
            return super::avx512::max_first_positive(keys);
        },
        // SAFETY: as above.
        Lanes::Avx2 => unsafe {
            if x.want_cols {
                super::avx2::col_max(keys, cb, ci, iu);
            }
            return super::avx2::max_first_positive(keys);
        },
        Lanes::Scalar => {}
    }
    if x.want_cols {
        for ((v, b), c) in keys.iter().zip(cb.iter_mut()).zip(ci.iter_mut()) {
            let better = *v > *b;
            *b = if better { *v } else { *b };
            *c = if better { iu } else { *c };
        }
    }
    let mx = max_lanes(keys);
    if mx > 0.0 {
        first_eq(keys, mx).map(|j| (j, mx))
    } else {
        None
    }
}

/// Noisy-AND posterior from a rank key, as `rank_keys_to_posteriors` computes it.
#[inline(always)]
fn posterior(key: f32, c: f64) -> f32 {
    let o = key as f64 * c;
    if o < f64::INFINITY {
        (o / (1.0 + o)) as f32
    } else {
        1.0
    }
}

/// One band of rows `t * band ..`. With `out = Some((pa, pb, pf))` the three output rows are
/// written there; without, the softmax rows live in `tmp` and no posterior matrix is formed.
#[inline(always)]
fn band_kernel(
    x: &Ctx<'_>,
    t: usize,
    out: BandOut<'_>,
    best: &mut [Option<(usize, f32)>],
    tmp: &mut Tmp,
    cbi: &mut ColBest,
) {
    let cols = x.cols;
    let Tmp {
        a,
        b,
        keys,
        band_a,
        band_b,
    } = tmp;
    let r0 = t * x.band;
    let n = best.len();
    band_rows(x.a.sim, r0, n, band_a);
    if !x.only_a {
        band_rows(x.b.sim, r0, n, band_b);
    }
    match out {
        Some((pa, pb, pf)) => {
            let rows = pa.chunks_mut(cols).zip(pb.chunks_mut(cols));
            for (k, ((ra, rb), rf)) in rows.zip(pf.chunks_mut(cols)).enumerate() {
                let s = (
                    sim_row(x.a.sim, band_a, r0, k, cols),
                    sim_row(x.b.sim, band_b, r0, k, cols),
                );
                best[k] = row_step(x, r0 + k, s, ra, rb, Some(rf), keys, cbi);
            }
        }
        None => {
            for (k, bt) in best.iter_mut().enumerate() {
                let sb = if x.only_a {
                    &[][..]
                } else {
                    sim_row(x.b.sim, band_b, r0, k, cols)
                };
                let s = (sim_row(x.a.sim, band_a, r0, k, cols), sb);
                *bt = row_step(x, r0 + k, s, a, b, None, keys, cbi);
            }
        }
    }
}

/// Rows `r0 .. r0 + n` of a feature-backed similarity into `buf` (n x cols; nothing for a
/// dense one, whose rows are read in place).
#[inline(always)]
fn band_rows(sim: Sim<'_>, r0: usize, n: usize, buf: &mut Vec<f32>) {
    if let Sim::Features { src, tgt } = sim {
        let (d, cols) = (src.dim, tgt.len());
        buf.resize(n * cols, 0.0);
        super::similarity::dot_band(&src.data[r0 * d..(r0 + n) * d], tgt, buf);
    }
}

/// Row `r0 + k` of `sim`: in place for a dense matrix, from the band buffer otherwise.
#[inline(always)]
fn sim_row<'s>(sim: Sim<'s>, buf: &'s [f32], r0: usize, k: usize, cols: usize) -> &'s [f32] {
    match sim {
        Sim::Dense(m) => m.row(r0 + k),
        Sim::Features { .. } => &buf[k * cols..(k + 1) * cols],
    }
}

/// The output rows of one band: `(p_img, p_geo, fused)`.
type BandOut<'a> = Option<(&'a mut [f32], &'a mut [f32], &'a mut [f32])>;

/// Row-sized scratch buffers of one task.
struct Tmp {
    a: Vec<f32>,
    b: Vec<f32>,
    keys: Vec<f32>,
    /// One band of similarity rows per feature-backed branch (empty for a dense one).
    band_a: Vec<f32>,
    band_b: Vec<f32>,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn band_kernel_avx2(
    x: &Ctx<'_>,
    t: usize,
    out: BandOut<'_>,
    best: &mut [Option<(usize, f32)>],
    tmp: &mut Tmp,
    cbi: &mut ColBest,
) {
    band_kernel(x, t, out, best, tmp, cbi)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2")]
unsafe fn band_kernel_avx512(
    x: &Ctx<'_>,
    t: usize,
    out: BandOut<'_>,
    best: &mut [Option<(usize, f32)>],
    tmp: &mut Tmp,
    cbi: &mut ColBest,
) {
    band_kernel(x, t, out, best, tmp, cbi)
}

/// Row softmax of both branches, Noisy-AND (stable, prior `prior` or 1 / (N M)) and
/// `selection` (MutualNn or RowNn; anything else is an error), in one pass. With
/// `materialise` the posteriors `(p_img, p_geo, fused)` are returned as well; without, no
/// N x M matrix is allocated (memory O(N + M) per task).
pub(crate) fn row_softmax_noisy_and(
    a: &Branch<'_>,
    b: &Branch<'_>,
    prior: Option<f64>,
    selection: Selection,
    materialise: bool,
) -> Result<FusedOut> {
    one_pass(a, Some(b), prior, selection, materialise)
}

/// The image branch alone (row softmax, then `selection`), in the same pass as
/// [`row_softmax_noisy_and`]: the correspondences `select` gives on `calibrate`'s row-softmax
/// posteriors of `a` (same order and scores); no N x M matrix.
pub(crate) fn row_softmax_image_only(a: &Branch<'_>, selection: Selection) -> Result<FusedOut> {
    one_pass(a, None, None, selection, false)
}

fn one_pass(
    a: &Branch<'_>,
    b: Option<&Branch<'_>>,
    prior: Option<f64>,
    selection: Selection,
    materialise: bool,
) -> Result<FusedOut> {
    let only_a = b.is_none();
    if only_a && materialise {
        return Err(Error::Invalid(
            "fused row softmax: the image-only pass forms no posterior matrices".into(),
        ));
    }
    let b = b.unwrap_or(a);
    let want_cols = match selection {
        Selection::MutualNn => true,
        Selection::RowNn => false,
        Selection::TopK(_) => {
            return Err(Error::Invalid(
                "fused row-softmax Noisy-AND: top-k selection is not supported here".into(),
            ))
        }
    };
    check_tau(a.tau)?;
    check_tau(b.tau)?;
    let (rows, cols) = a.sim.shape();
    if b.sim.shape() != (rows, cols) {
        return Err(Error::Shape(format!(
            "fusion: image similarity is {rows} x {cols}, geometric similarity is {} x {}",
            b.sim.shape().0,
            b.sim.shape().1
        )));
    }
    let mut mats = if materialise {
        Some((
            DenseMatrix::zeros(rows, cols)?,
            DenseMatrix::zeros(rows, cols)?,
            DenseMatrix::zeros(rows, cols)?,
        ))
    } else {
        None
    };
    if rows == 0 || cols == 0 {
        return Ok(FusedOut {
            mats,
            correspondences: Vec::new(),
        });
    }
    let prior = prior.unwrap_or_else(|| default_prior(rows, cols));
    let prior_ok = prior > 0.0 && prior < 1.0;
    if !only_a && !prior_ok {
        return Err(Error::Param(format!(
            "fusion prior must lie strictly between 0 and 1, found {prior}"
        )));
    }
    let (bias_a, bias_b) = (bias(cols, a.col_valid), bias(cols, b.col_valid));
    let streamed = |s: Sim<'_>| matches!(s, Sim::Features { .. });
    for (what, br) in [("image", a), ("geometric", b)] {
        if let Sim::Features { src, tgt } = br.sim {
            if src.dim != tgt.dim() || src.dim == 0 {
                return Err(Error::Shape(format!(
                    "fusion: {what} features are {}-D (source) and {}-D (target)",
                    src.dim,
                    tgt.dim()
                )));
            }
        }
    }
    // Feature-backed rows are formed a band at a time by `dot_band`: 64+ rows keep the sgemm
    // fallback's packing of the target features amortised (as `cosine_similarity`'s bands).
    let band = if streamed(a.sim) || (!only_a && streamed(b.sim)) {
        rows_per_task(rows, cols, 1 << 18).max(64).min(rows)
    } else {
        rows_per_task(rows, cols, 1 << 16)
    };
    let c = (1.0 - prior) / prior;
    let x = Ctx {
        cols,
        band,
        a,
        b,
        bias_a: &bias_a,
        bias_b: &bias_b,
        c,
        want_cols,
        only_a,
        lanes: match crate::simd::features().float_isa() {
            Isa::Avx512 if crate::simd::features().avx2 => Lanes::Avx512,
            _ if crate::simd::features().avx2 => Lanes::Avx2,
            _ => Lanes::Scalar,
        },
    };
    let isa = crate::simd::features().float_isa();
    let mut best: Vec<Option<(usize, f32)>> = vec![None; rows];
    let col_len = if want_cols { cols } else { 0 };
    let init = || {
        let tmp = Tmp {
            a: vec![0.0f32; if materialise { 0 } else { cols }],
            b: vec![0.0f32; if materialise { 0 } else { cols }],
            keys: vec![0.0f32; cols],
            band_a: Vec::new(),
            band_b: Vec::new(),
        };
        ((vec![0.0f32; col_len], vec![u32::MAX; col_len]), tmp)
    };
    let step = |(mut cbi, mut tmp): (ColBest, Tmp),
                (t, out, bt): (usize, BandOut<'_>, &mut [Option<(usize, f32)>])| {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU supports these features (checked at run time by `isa`).
            Isa::Avx512 => unsafe { band_kernel_avx512(&x, t, out, bt, &mut tmp, &mut cbi) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            Isa::Avx2 => unsafe { band_kernel_avx2(&x, t, out, bt, &mut tmp, &mut cbi) },
            _ => band_kernel(&x, t, out, bt, &mut tmp, &mut cbi),
        }
        (cbi, tmp)
    };
    // Folds cover consecutive bands and are reduced in order; only a strictly greater key
    // replaces, so column ties go to the lowest row.
    let merge = |(mut cb, mut ci): ColBest, (cb2, ci2): ColBest| {
        for j in 0..cb.len() {
            if cb2[j] > cb[j] {
                cb[j] = cb2[j];
                ci[j] = ci2[j];
            }
        }
        (cb, ci)
    };
    let chunk = band * cols;
    let (_, cidx) = match &mut mats {
        Some((pa, pb, pf)) => pa
            .data
            .par_chunks_mut(chunk)
            .zip(pb.data.par_chunks_mut(chunk))
            .zip(pf.data.par_chunks_mut(chunk))
            .zip(best.par_chunks_mut(band))
            .enumerate()
            .fold(init, |acc, (t, (((pa, pb), pf), bt))| {
                step(acc, (t, Some((pa, pb, pf)), bt))
            })
            .map(|(cbi, _)| cbi)
            .reduce_with(merge),
        None => best
            .par_chunks_mut(band)
            .enumerate()
            .fold(init, |acc, (t, bt)| step(acc, (t, None, bt)))
            .map(|(cbi, _)| cbi)
            .reduce_with(merge),
    }
    .unwrap_or_default();
    // Sorted by key (as the general path ranks), then scored by the posterior.
    let mut keyed: Vec<Correspondence> = best
        .iter()
        .enumerate()
        .filter_map(|(i, b)| {
            let (j, key) = (*b)?;
            if want_cols && cidx[j] != i as u32 {
                return None;
            }
            Some(Correspondence {
                src: i as u32,
                tgt: j as u32,
                score: key,
            })
        })
        .collect();
    keyed.sort_unstable_by(order);
    for k in &mut keyed {
        if !only_a {
            k.score = posterior(k.score, c);
        }
    }
    Ok(FusedOut {
        mats,
        correspondences: keyed,
    })
}
