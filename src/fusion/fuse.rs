//! Fusion of the image and geometric correspondence posteriors (paper eq. 6-7, appendix A;
//! reference §8.4), and the "fuse-then-match" feature-concatenation baseline.
//!
//! Noisy-AND (paper eq. 6) under conditional independence of the two similarities given the
//! match: `o(p_f) = o(p_img) o(p_geo) / o(pi)` with odds `o(x) = x / (1 - x)`, i.e.
//! `logit(p_f) = logit(p_img) + logit(p_geo) - logit(pi)`. The paper-faithful mode evaluates
//! exactly this identity as `p_f = a / (a + b)` with `a = p_img p_geo (1 - pi)` and
//! `b = (1 - p_img)(1 - p_geo) pi` in f64: `ln a - ln b` *is* the log-odds sum above, and f64
//! holds products of f32 probabilities and priors without under- or overflow, so no log/exp
//! per entry is needed. p = 0 or 1 and pi = 1e-9 give no NaN/inf; a branch that is certain of a
//! non-match (p = 0) vetoes the pair, also when the other branch says p = 1.
//!
//! `exact_reference` reproduces the reference's float32 formula and operation order instead:
//! `num = Pr*Pg*(1-pi); den = num + (1-Pr)*(1-Pg)*pi; F = num / (den + 1e-8)`.

use super::similarity::normalize_rows;
use crate::features::Features;
use crate::matrix::{check_masks, rows_per_task, DenseMatrix};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How the two modality posteriors become one score matrix.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
pub enum FusionMode {
    /// Joint posterior (paper eq. 6): both modalities must support a match.
    #[default]
    NoisyAnd,
    /// Disjunctive posterior (paper eq. 7): `1 - (1 - p_img)(1 - p_geo)`.
    NoisyOr,
    /// The image-branch posterior alone.
    #[value(name = "image")]
    ImageOnly,
    /// The geometric-branch posterior alone.
    #[value(name = "geometry")]
    GeometryOnly,
    /// Fuse-then-match baseline: concatenate L2-normalised features, then one cosine
    /// similarity calibrated like a single branch.
    Concat,
    /// The Noisy-AND correspondences and the geometric branch's own (row NN) ones, estimated
    /// together: a weak image branch cannot veto the geometric matches.
    /// Its posterior (inspector, export) is Noisy-AND's.
    Union,
    /// The union's, the geometric branch's, Noisy-AND's and the image branch's poses, of which
    /// the one most consistent with both scans' depth views is kept (the largest share of seen
    /// keypoints on an observed surface rather than in observed free space, as a 95 % lower
    /// bound). Its posterior is Noisy-AND's.
    Visibility,
}

impl FusionMode {
    /// The mode the CLI and the inspector use when the image branch runs and none is chosen
    /// (`FusionParams::default()` stays the paper's Noisy-AND).
    pub const DEFAULT_WITH_IMAGE: FusionMode = FusionMode::Visibility;

    /// The mode a run uses unless one is chosen, the same in `register`, `bench`, the
    /// inspector's branch switch and Python: [`Self::DEFAULT_WITH_IMAGE`] when the image
    /// branch runs, the paper's Noisy-AND under `reference` (the authors' code), and
    /// geometry only without images (what runs then, whatever the mode says).
    pub fn default_for(image_branch: bool, reference: bool) -> FusionMode {
        match (image_branch, reference) {
            (false, _) => FusionMode::GeometryOnly,
            (true, true) => FusionMode::NoisyAnd,
            (true, false) => Self::DEFAULT_WITH_IMAGE,
        }
    }

    /// Every mode, in the order the inspector lists them.
    pub const ALL: [FusionMode; 7] = [
        FusionMode::Visibility,
        FusionMode::Union,
        FusionMode::NoisyAnd,
        FusionMode::NoisyOr,
        FusionMode::Concat,
        FusionMode::ImageOnly,
        FusionMode::GeometryOnly,
    ];

    pub fn label(self) -> &'static str {
        match self {
            FusionMode::NoisyAnd => "Noisy-AND",
            FusionMode::NoisyOr => "Noisy-OR",
            FusionMode::Concat => "Concatenation",
            FusionMode::ImageOnly => "Image only",
            FusionMode::GeometryOnly => "Geometry only",
            FusionMode::Union => "Union (Noisy-AND + geometry correspondences)",
            FusionMode::Visibility => "Visibility (union, geometry, Noisy-AND or image pose)",
        }
    }

    /// The mode whose posterior matrix this mode shows and selects from: Noisy-AND for
    /// `Union` and `Visibility` (selections and poses, not a matrix), the mode itself
    /// otherwise.
    pub fn matrix_mode(self) -> FusionMode {
        match self {
            FusionMode::Union | FusionMode::Visibility => FusionMode::NoisyAnd,
            m => m,
        }
    }
}

/// The paper's uniform prior `pi = 1 / (N_src N_tgt)`.
pub fn default_prior(rows: usize, cols: usize) -> f64 {
    1.0 / (rows as f64 * cols as f64)
}

#[inline(always)]
fn clamp01(p: f32) -> f64 {
    // Branch-free; NaN fails `p > 0` and becomes 0, an invalid entry.
    let x = if p > 0.0 { p } else { 0.0 };
    (if x < 1.0 { x } else { 1.0 }) as f64
}

/// The two terms of eq. 6: `a = p_i p_g (1 - pi)`, `b = (1 - p_i)(1 - p_g) pi`, in f64.
#[inline(always)]
fn and_terms(p_img: f32, p_geo: f32, prior: f64, one_minus_prior: f64) -> (f64, f64) {
    let (x, y) = (clamp01(p_img), clamp01(p_geo));
    (x * y * one_minus_prior, (1.0 - x) * (1.0 - y) * prior)
}

/// `o(p_img) o(p_geo)` in f32: the product of the two branch odds. Noisy-AND's odds are this
/// divided by the constant `o(pi)`, so it ranks pairs exactly as the fused posterior does, but
/// it does not saturate: near 1 the f32 posterior rounds to 1.0 for many pairs (with pi ~ 1e-8,
/// any pair whose branch posteriors are both above ~0.5), which would turn ranking into ties.
/// It stays below 3e14 for f32 inputs below 1; `inf` when a posterior is exactly 1; 0 = p_f = 0.
#[inline(always)]
fn odds_product(p_img: f32, p_geo: f32) -> f32 {
    let x = if p_img > 1.0 { 1.0 } else { p_img };
    let y = if p_geo > 1.0 { 1.0 } else { p_geo };
    let a = x * y;
    // NaN fails `a > 0` and becomes 0.
    if a > 0.0 {
        a / ((1.0 - x) * (1.0 - y))
    } else {
        0.0
    }
}

/// Noisy-AND of two posteriors with prior `pi` (paper eq. 6), evaluated stably (module docs).
#[inline]
pub fn noisy_and(p_img: f32, p_geo: f32, prior: f64) -> f32 {
    let (a, b) = and_terms(p_img, p_geo, prior, 1.0 - prior);
    if a > 0.0 {
        (a / (a + b)) as f32
    } else {
        0.0
    }
}

/// A monotone, non-saturating ranking key for the Noisy-AND posterior, `o(p_img) o(p_geo)`
/// (see `odds_product`); [`rank_keys_to_posteriors`] turns it into `p_f`. 0 means p_f = 0.
#[inline]
pub fn noisy_and_rank_key(p_img: f32, p_geo: f32) -> f32 {
    odds_product(p_img, p_geo)
}

/// The reference's float32 Noisy-AND, operation for operation (reference §8.4).
#[inline]
pub fn noisy_and_reference(p_img: f32, p_geo: f32, prior: f64) -> f32 {
    // `pi` and `1 - pi` are Python floats; torch rounds them to f32 when multiplying.
    let pi = prior as f32;
    let one_minus_pi = (1.0 - prior) as f32;
    let num = p_img * p_geo * one_minus_pi;
    let den = num + (1.0 - p_img) * (1.0 - p_geo) * pi;
    num / (den + 1e-8f32)
}

/// Noisy-OR (paper eq. 7), as `p_i + p_g (1 - p_i)` in f64 so tiny posteriors are not lost.
#[inline]
pub fn noisy_or(p_img: f32, p_geo: f32) -> f32 {
    let (x, y) = (clamp01(p_img), clamp01(p_geo));
    (x + y * (1.0 - x)) as f32
}

/// The reference's float32 Noisy-OR, `1 - (1 - Pr)(1 - Pg)`.
#[inline]
pub fn noisy_or_reference(p_img: f32, p_geo: f32) -> f32 {
    1.0 - (1.0 - p_img) * (1.0 - p_geo)
}

fn check_prior(prior: f64) -> Result<()> {
    if prior > 0.0 && prior < 1.0 {
        Ok(())
    } else {
        Err(Error::Param(format!(
            "fusion prior must lie strictly between 0 and 1, found {prior}"
        )))
    }
}

fn same_shape(a: &DenseMatrix, b: &DenseMatrix) -> Result<()> {
    for (what, m) in [("image", a), ("geometric", b)] {
        if m.data.len() != m.rows * m.cols {
            return Err(Error::Shape(format!(
                "fusion: {what} posterior holds {} values, expected {} x {}",
                m.data.len(),
                m.rows,
                m.cols
            )));
        }
    }
    if a.shape() != b.shape() {
        return Err(Error::Shape(format!(
            "fusion: image posterior is {} x {}, geometric posterior is {} x {}",
            a.rows, a.cols, b.rows, b.cols
        )));
    }
    Ok(())
}

/// `out[k] = f(a[k], b[k])` in parallel.
fn zip_into(
    out: &mut [f32],
    a: &[f32],
    b: &[f32],
    cols: usize,
    f: impl Fn(f32, f32) -> f32 + Sync,
) {
    let chunk = rows_per_task(out.len() / cols.max(1), cols, 1 << 16) * cols.max(1);
    out.par_chunks_mut(chunk.max(1))
        .zip(a.par_chunks(chunk.max(1)).zip(b.par_chunks(chunk.max(1))))
        .for_each(|(o, (x, y))| {
            for (o, (x, y)) in o.iter_mut().zip(x.iter().zip(y)) {
                *o = f(*x, *y);
            }
        });
}

/// Writes the fusion of `p_img` and `p_geo` into `out` (which may be a fresh or recycled
/// buffer of the same shape). Only the two-branch modes are accepted here.
pub fn fuse_into(
    out: &mut DenseMatrix,
    p_img: &DenseMatrix,
    p_geo: &DenseMatrix,
    mode: FusionMode,
    prior: Option<f64>,
    exact_reference: bool,
) -> Result<()> {
    same_shape(p_img, p_geo)?;
    if out.shape() != p_img.shape() || out.data.len() != p_img.data.len() {
        return Err(Error::Shape(format!(
            "fusion: output is {} x {}, posteriors are {} x {}",
            out.rows, out.cols, p_img.rows, p_img.cols
        )));
    }
    if p_img.data.is_empty() {
        return Ok(());
    }
    let prior = prior.unwrap_or_else(|| default_prior(p_img.rows, p_img.cols));
    check_prior(prior)?;
    let (a, b, cols) = (&p_img.data, &p_geo.data, p_img.cols);
    let omp = 1.0 - prior;
    match (mode, exact_reference) {
        (FusionMode::NoisyAnd, false) => zip_into(&mut out.data, a, b, cols, |x, y| {
            let (s, t) = and_terms(x, y, prior, omp);
            if s > 0.0 {
                (s / (s + t)) as f32
            } else {
                0.0
            }
        }),
        (FusionMode::NoisyAnd, true) => zip_into(&mut out.data, a, b, cols, |x, y| {
            noisy_and_reference(x, y, prior)
        }),
        (FusionMode::NoisyOr, false) => zip_into(&mut out.data, a, b, cols, noisy_or),
        (FusionMode::NoisyOr, true) => zip_into(&mut out.data, a, b, cols, noisy_or_reference),
        (m, _) => {
            return Err(Error::Invalid(format!(
                "fuse_into: {m:?} is not a two-branch posterior fusion"
            )))
        }
    }
    Ok(())
}

fn need<'a>(m: Option<&'a DenseMatrix>, mode: FusionMode, what: &str) -> Result<&'a DenseMatrix> {
    m.ok_or_else(|| Error::Missing(format!("fusion mode {mode:?} needs the {what} posterior")))
}

/// Fuses the modality posteriors. `prior` defaults to `1 / (N M)`. `Concat` is rejected here:
/// it fuses features before matching (see [`concat_features`], [`concat_similarity`]).
pub fn fuse(
    p_img: Option<&DenseMatrix>,
    p_geo: Option<&DenseMatrix>,
    mode: FusionMode,
    prior: Option<f64>,
    exact_reference: bool,
) -> Result<DenseMatrix> {
    let mode = mode.matrix_mode();
    match mode {
        FusionMode::ImageOnly => Ok(need(p_img, mode, "image")?.clone()),
        FusionMode::GeometryOnly => Ok(need(p_geo, mode, "geometric")?.clone()),
        FusionMode::Concat => Err(Error::Invalid(
            "fusion mode Concat fuses features before matching: use concat_features or \
             concat_similarity, then calibrate that one similarity"
                .into(),
        )),
        FusionMode::NoisyAnd | FusionMode::NoisyOr | FusionMode::Union | FusionMode::Visibility => {
            let (a, b) = (need(p_img, mode, "image")?, need(p_geo, mode, "geometric")?);
            same_shape(a, b)?;
            let mut out = DenseMatrix::zeros(a.rows, a.cols)?;
            fuse_into(&mut out, a, b, mode, prior, exact_reference)?;
            Ok(out)
        }
    }
}

/// The matrix of [`noisy_and_rank_key`]s: rank by it, then [`rank_keys_to_posteriors`].
pub fn noisy_and_rank_keys(p_img: &DenseMatrix, p_geo: &DenseMatrix) -> Result<DenseMatrix> {
    same_shape(p_img, p_geo)?;
    let mut out = DenseMatrix::zeros(p_img.rows, p_img.cols)?;
    zip_into(
        &mut out.data,
        &p_img.data,
        &p_geo.data,
        p_img.cols,
        odds_product,
    );
    Ok(out)
}

/// Turns a matrix of [`noisy_and_rank_key`]s into the Noisy-AND posteriors in place:
/// `p = o / (1 + o)` with `o = key / o(pi)` (relative error about 2e-7 against [`fuse`]).
pub fn rank_keys_to_posteriors(keys: &mut DenseMatrix, prior: Option<f64>) -> Result<()> {
    if keys.data.is_empty() {
        return Ok(());
    }
    let prior = prior.unwrap_or_else(|| default_prior(keys.rows, keys.cols));
    check_prior(prior)?;
    let c = (1.0 - prior) / prior;
    let cols = keys.cols.max(1);
    let chunk = rows_per_task(keys.data.len() / cols, cols, 1 << 16) * cols;
    keys.data.par_chunks_mut(chunk).for_each(|ch| {
        for v in ch.iter_mut() {
            let o = *v as f64 * c;
            *v = if o < f64::INFINITY {
                (o / (1.0 + o)) as f32
            } else {
                1.0
            };
        }
    });
    Ok(())
}

fn check_weight(w_img: f32) -> Result<()> {
    if (0.0..=1.0).contains(&w_img) {
        Ok(())
    } else {
        Err(Error::Param(format!(
            "concatenation: image weight must lie in [0, 1], found {w_img}"
        )))
    }
}

/// Fuse-then-match features: row i is `[sqrt(w) img_i / |img_i|, sqrt(1 - w) geo_i / |geo_i|]`,
/// with the image block zero where point i has no pixel. For two mapped points the cosine
/// similarity of these rows is `w cos_img + (1 - w) cos_geo`.
pub fn concat_features(
    img: &Features,
    img_valid: &[bool],
    geo: &Features,
    w_img: f32,
) -> Result<Features> {
    check_weight(w_img)?;
    let n = geo.len();
    if img.len() != n || img_valid.len() != n {
        return Err(Error::Shape(format!(
            "concatenation: {} image feature rows, {} validity flags, {} geometric feature rows",
            img.len(),
            img_valid.len(),
            n
        )));
    }
    let (ni, ng) = (normalize_rows(img), normalize_rows(geo));
    let (di, dg) = (img.dim, geo.dim);
    let (wi, wg) = (w_img.sqrt(), (1.0 - w_img).sqrt());
    let mut data = vec![0.0f32; n * (di + dg)];
    data.par_chunks_mut((di + dg).max(1))
        .enumerate()
        .for_each(|(i, row)| {
            if img_valid[i] {
                for (o, v) in row[..di].iter_mut().zip(ni.row(i)) {
                    *o = wi * v;
                }
            }
            for (o, v) in row[di..].iter_mut().zip(ng.row(i)) {
                *o = wg * v;
            }
        });
    Ok(Features::new(di + dg, data))
}

/// The cosine similarity of [`concat_features`] computed from the two branch similarities,
/// without the features: `(w vi vj S_img + (1 - w) S_geo) / (|x_i| |y_j|)` with
/// `|x_i| = sqrt(w vi + 1 - w)` (vi = row i mapped, vj = column j mapped).
pub fn concat_similarity(
    s_img: &DenseMatrix,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
    s_geo: &DenseMatrix,
    w_img: f32,
) -> Result<DenseMatrix> {
    check_weight(w_img)?;
    same_shape(s_img, s_geo)?;
    check_masks(
        "concatenation",
        s_img.rows,
        s_img.cols,
        row_valid,
        col_valid,
    )?;
    let (rows, cols) = s_img.shape();
    let mut out = DenseMatrix::zeros(rows, cols)?;
    if out.data.is_empty() {
        return Ok(out);
    }
    let inv_norm = |valid: bool| {
        let n = (w_img * valid as u8 as f32 + 1.0 - w_img).sqrt();
        if n > 1e-6 {
            1.0 / n
        } else {
            0.0
        }
    };
    let cv: Vec<f32> = (0..cols)
        .map(|j| col_valid.is_none_or(|c| c[j]) as u8 as f32)
        .collect();
    let cinv: Vec<f32> = cv.iter().map(|&v| inv_norm(v > 0.0)).collect();
    out.data
        .par_chunks_mut(cols)
        .enumerate()
        .with_min_len(rows_per_task(rows, cols, 1 << 15))
        .for_each(|(i, o)| {
            let vi = row_valid.is_none_or(|r| r[i]);
            let (si, sg) = (s_img.row(i), s_geo.row(i));
            let ri = inv_norm(vi);
            let wi = if vi { w_img } else { 0.0 };
            for (o, ((c, s), (g, r))) in o
                .iter_mut()
                .zip(cv.iter().zip(si).zip(sg.iter().zip(&cinv)))
            {
                *o = (wi * c * s + (1.0 - w_img) * g) * ri * r;
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::similarity::cosine_similarity;
    use crate::testing::Lcg;

    fn odds(x: f64) -> f64 {
        x / (1.0 - x)
    }

    #[test]
    fn noisy_and_is_the_odds_product_of_appendix_a() {
        let mut s = Lcg(3);
        for _ in 0..2000 {
            let (pi_, pg) = (
                s.unit_f32().clamp(1e-6, 0.999),
                s.unit_f32().clamp(1e-6, 0.999),
            );
            for prior in [1e-8, 4e-5, 0.01, 0.3] {
                let pf = noisy_and(pi_, pg, prior) as f64;
                // o(p_f) = o(p_img) o(p_geo) / o(pi)
                let want_odds = odds(pi_ as f64) * odds(pg as f64) / odds(prior);
                let want = want_odds / (1.0 + want_odds);
                assert!(
                    (pf - want).abs() <= 2e-7 * want.max(1e-30) + 1e-37,
                    "{pi_} {pg} {prior}"
                );
                // Equivalent log-odds statement: logit(p_f) = logit(p_i) + logit(p_g) - logit(pi).
                if pf < 0.99 && pf > 1e-30 {
                    let lf = odds(pf).ln();
                    let lw = odds(pi_ as f64).ln() + odds(pg as f64).ln() - odds(prior).ln();
                    assert!((lf - lw).abs() < 1e-5 * lw.abs().max(1.0));
                }
                // The ranking key is o(p_f)^(1/4).
                // The ranking key is o(p_img) o(p_geo) = o(p_f) o(pi).
                let k = noisy_and_rank_key(pi_, pg) as f64;
                assert!((k / odds(prior) - want_odds).abs() <= 1e-6 * want_odds);
                let mut km = DenseMatrix::from_vec(1, 1, vec![k as f32]).unwrap();
                rank_keys_to_posteriors(&mut km, Some(prior)).unwrap();
                assert!((km.data[0] as f64 - want).abs() <= 1e-6 * want.max(1e-30) + 1e-37);
            }
        }
    }

    #[test]
    fn uninformative_branch_leaves_the_other_unchanged() {
        let mut s = Lcg(5);
        for prior in [1e-9f64, 1e-4, 0.2] {
            for _ in 0..500 {
                let p = s.unit_f32();
                let f = noisy_and(p, prior as f32, prior);
                let g = noisy_and(prior as f32, p, prior);
                // p_geo = pi is rounded to f32, hence the tolerance.
                assert!((f - p).abs() <= 1e-6 * p.max(1e-6), "{p} {prior}: {f}");
                assert_eq!(f, g);
            }
        }
    }

    #[test]
    fn extreme_probabilities_give_no_nan() {
        let ps = [0.0f32, 1.0, 1e-30, 1.0 - 1e-7, 1e-45, 0.5, f32::NAN];
        for &a in &ps {
            for &b in &ps {
                for prior in [1e-9, 1e-300, 0.5] {
                    let f = noisy_and(a, b, prior);
                    assert!(
                        f.is_finite() && (0.0..=1.0).contains(&f),
                        "{a} {b} {prior}: {f}"
                    );
                    let k = noisy_and_rank_key(a, b);
                    assert!(!k.is_nan() && k >= 0.0);
                    let o = noisy_or(a, b);
                    assert!(o.is_finite() && (0.0..=1.0).contains(&o));
                }
            }
        }
        // Certain agreement, certain veto, and the conflict (veto wins).
        assert_eq!(noisy_and(1.0, 1.0, 1e-9), 1.0);
        assert_eq!(noisy_and(0.0, 0.9, 1e-9), 0.0);
        assert_eq!(noisy_and(1.0, 0.0, 1e-9), 0.0);
        // Tiny but non-zero evidence is kept, not flushed: o = 1e-30 * 1 / 1e-9.
        let f = noisy_and(1e-30, 0.5, 1e-9) as f64;
        assert!((f / 1e-21 - 1.0).abs() < 1e-5, "{f}");
        // Saturation: the f32 posterior is 1.0 but the key still ranks.
        assert_eq!(noisy_and(0.9, 0.9, 1e-8), 1.0);
        assert!(noisy_and_rank_key(0.95, 0.9) > noisy_and_rank_key(0.9, 0.9));
        assert_eq!(noisy_and_rank_key(1.0, 0.5), f32::INFINITY);
        assert_eq!(noisy_and_rank_key(1.0, 0.0), 0.0);
    }

    #[test]
    fn exact_reference_matches_f32_transcription() {
        let (n, m) = (17, 23);
        let mut s = Lcg(11);
        let a = DenseMatrix::from_fn(n, m, |_, _| s.unit_f32()).unwrap();
        let mut b = DenseMatrix::from_fn(n, m, |_, _| s.unit_f32()).unwrap();
        b.data[0] = 0.0;
        b.data[1] = 1.0;
        let f = fuse(Some(&a), Some(&b), FusionMode::NoisyAnd, None, true).unwrap();
        let pi: f64 = 1.0 / ((n * m) as f64);
        for k in 0..n * m {
            let (pr, pg) = (a.data[k], b.data[k]);
            let num: f32 = pr * pg * ((1.0 - pi) as f32);
            let den: f32 = num + (1.0f32 - pr) * (1.0f32 - pg) * (pi as f32);
            assert_eq!(f.data[k].to_bits(), (num / (den + 1e-8f32)).to_bits());
        }
        let o = fuse(Some(&a), Some(&b), FusionMode::NoisyOr, None, true).unwrap();
        for k in 0..n * m {
            assert_eq!(
                o.data[k],
                1.0f32 - (1.0f32 - a.data[k]) * (1.0f32 - b.data[k])
            );
        }
        // The paper mode agrees with the closed form of eq. 6 away from the eps.
        let p = fuse(Some(&a), Some(&b), FusionMode::NoisyAnd, Some(0.01), false).unwrap();
        for k in 2..n * m {
            let (x, y) = (a.data[k] as f64, b.data[k] as f64);
            let want = x * y * 0.99 / (x * y * 0.99 + (1.0 - x) * (1.0 - y) * 0.01);
            assert!((p.data[k] as f64 - want).abs() < 1e-6);
        }
    }

    #[test]
    fn noisy_or_symmetry_and_bounds() {
        let mut s = Lcg(13);
        for _ in 0..1000 {
            let (a, b) = (s.unit_f32(), s.unit_f32());
            let o = noisy_or(a, b);
            assert_eq!(o, noisy_or(b, a));
            assert!(o >= a.max(b) - 1e-7 && o <= 1.0);
            assert!((o as f64 - (1.0 - (1.0 - a as f64) * (1.0 - b as f64))).abs() < 1e-7);
        }
        assert_eq!(noisy_or(0.0, 0.0), 0.0);
        assert_eq!(noisy_or(1.0, 0.3), 1.0);
        assert_eq!(noisy_or(1e-30, 0.0), 1e-30);
    }

    #[test]
    fn fuse_checks_shapes_and_modes() {
        let a = DenseMatrix::zeros(3, 4).unwrap();
        let b = DenseMatrix::zeros(4, 3).unwrap();
        assert!(fuse(Some(&a), Some(&b), FusionMode::NoisyAnd, None, false).is_err());
        assert!(fuse(Some(&a), None, FusionMode::NoisyOr, None, false).is_err());
        assert!(fuse(None, Some(&b), FusionMode::ImageOnly, None, false).is_err());
        assert!(fuse(Some(&a), Some(&a), FusionMode::Concat, None, false).is_err());
        assert!(fuse(Some(&a), Some(&a), FusionMode::NoisyAnd, Some(0.0), false).is_err());
        assert!(fuse(Some(&a), Some(&a), FusionMode::NoisyAnd, Some(1.5), false).is_err());
        assert_eq!(
            fuse(None, Some(&b), FusionMode::GeometryOnly, None, false).unwrap(),
            b
        );
    }

    #[test]
    fn concat_similarity_equals_cosine_of_concatenated_features() {
        let (n, m, di, dg) = (19, 27, 12, 9);
        let mut s = Lcg(17);
        let mut f = |rows: usize, d: usize| {
            Features::new(d, (0..rows * d).map(|_| s.unit_f32() - 0.5).collect())
        };
        let (is, it, gs, gt) = (f(n, di), f(m, di), f(n, dg), f(m, dg));
        let rv: Vec<bool> = (0..n).map(|i| i % 3 != 0).collect();
        let cv: Vec<bool> = (0..m).map(|j| j % 4 != 1).collect();
        for w in [0.0f32, 0.3, 0.5, 1.0] {
            let cs = concat_features(&is, &rv, &gs, w).unwrap();
            let ct = concat_features(&it, &cv, &gt, w).unwrap();
            let direct = cosine_similarity(&cs, &ct).unwrap();
            let si = cosine_similarity(&is, &it).unwrap();
            let sg = cosine_similarity(&gs, &gt).unwrap();
            let via = concat_similarity(&si, Some(&rv), Some(&cv), &sg, w).unwrap();
            for k in 0..n * m {
                assert!((direct.data[k] - via.data[k]).abs() < 2e-6, "w={w} k={k}");
            }
            // Two mapped points: weighted mean of the branch cosines.
            let (i, j) = (1, 0);
            assert!((via.get(i, j) - (w * si.get(i, j) + (1.0 - w) * sg.get(i, j))).abs() < 1e-6);
        }
        assert!(concat_features(&is, &rv[..3], &gs, 0.5).is_err());
        assert!(concat_features(&is, &rv, &gs, 1.5).is_err());
    }
}
