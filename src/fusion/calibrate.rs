//! Calibration of a similarity matrix into modality correspondence posteriors.
//!
//! - [`Calibration::RowSoftmax`] is the paper's eq. 5: `p_ij = softmax_j(S_ij / tau)`, one
//!   distribution over target points per source point.
//! - [`Calibration::DualSoftmax`] is the reference code's `rc_softmax` (reference §8.3):
//!   `P = sqrt(Pr * Pc + 1e-9)` with `Pr` the row softmax and `Pc` the column softmax of
//!   `S / tau`, invalid entries 0 (so every valid entry is at least sqrt(1e-9) ~ 3.2e-5).
//!
//! Invalid entries (row i invalid or column j invalid) are removed from both softmaxes
//! exactly (the reference's `finfo.min / 4 / T` overflows to -inf) and come out as 0; a row
//! or column with nothing valid is all 0. Every softmax subtracts its maximum first.
//! Everything works in place on the similarity buffer: no extra N x M matrix is allocated.

use crate::matrix::{check_masks, rows_per_task, DenseMatrix};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How a similarity matrix becomes a posterior matrix.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Calibration {
    /// Paper eq. 5: row softmax over targets of S / tau.
    RowSoftmax { tau: f32 },
    /// Reference §8.3: sqrt(row softmax * column softmax + 1e-9).
    DualSoftmax { tau: f32 },
}

impl Default for Calibration {
    /// The paper's calibration with the temperature the reference passes for both branches.
    fn default() -> Self {
        Calibration::RowSoftmax { tau: 0.1 }
    }
}

impl Calibration {
    pub fn tau(&self) -> f32 {
        match *self {
            Calibration::RowSoftmax { tau } | Calibration::DualSoftmax { tau } => tau,
        }
    }

    /// The temperature, for controls that edit it in place.
    pub fn tau_mut(&mut self) -> &mut f32 {
        match self {
            Calibration::RowSoftmax { tau } | Calibration::DualSoftmax { tau } => tau,
        }
    }

    /// Every calibration method, each with temperature `tau` (for a method choice that keeps
    /// the temperature).
    pub fn all_with_tau(tau: f32) -> [Calibration; 2] {
        [
            Calibration::RowSoftmax { tau },
            Calibration::DualSoftmax { tau },
        ]
    }

    /// The same method with temperature `tau`.
    pub fn with_tau(mut self, tau: f32) -> Calibration {
        *self.tau_mut() = tau;
        self
    }

    pub fn label(&self) -> &'static str {
        match self {
            Calibration::RowSoftmax { .. } => "Row softmax",
            Calibration::DualSoftmax { .. } => "Dual softmax",
        }
    }
}

/// `--calibration row|dual`; the temperature comes from `--tau-img` / `--tau-geo`.
impl clap::ValueEnum for Calibration {
    fn value_variants<'a>() -> &'a [Self] {
        const V: [Calibration; 2] = [
            Calibration::RowSoftmax { tau: 0.1 },
            Calibration::DualSoftmax { tau: 0.1 },
        ];
        &V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(match self {
            Calibration::RowSoftmax { .. } => clap::builder::PossibleValue::new("row")
                .help("The paper's row softmax over target points (eq. 5)"),
            Calibration::DualSoftmax { .. } => clap::builder::PossibleValue::new("dual")
                .help("The reference code's dual softmax sqrt(Pr*Pc + 1e-9)"),
        })
    }
}

/// The reference's floor inside the square root of the dual softmax.
pub const DUAL_SOFTMAX_EPS: f32 = 1e-9;

/// Calibrates a copy of `sim` (see the module docs).
pub fn calibrate(
    sim: &DenseMatrix,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
    cal: Calibration,
) -> Result<DenseMatrix> {
    check_masks("calibrate", sim.rows, sim.cols, row_valid, col_valid)?;
    let mut out = sim.duplicate()?;
    calibrate_in_place(&mut out, row_valid, col_valid, cal)?;
    Ok(out)
}

/// Calibrates `m` in place (see the module docs).
pub fn calibrate_in_place(
    m: &mut DenseMatrix,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
    cal: Calibration,
) -> Result<()> {
    check_masks("calibrate", m.rows, m.cols, row_valid, col_valid)?;
    if m.data.len() != m.rows * m.cols {
        return Err(Error::Shape(format!(
            "calibrate: matrix holds {} values, expected {} x {}",
            m.data.len(),
            m.rows,
            m.cols
        )));
    }
    let tau = cal.tau();
    if !(tau.is_finite() && tau > 0.0) {
        return Err(Error::Param(format!(
            "calibrate: temperature must be a positive finite number, found {tau}"
        )));
    }
    if m.rows == 0 || m.cols == 0 {
        return Ok(());
    }
    let bias = col_bias(m.cols, col_valid);
    match cal {
        Calibration::RowSoftmax { .. } => row_softmax(m, row_valid, &bias, 1.0 / tau),
        Calibration::DualSoftmax { .. } => dual_softmax(m, row_valid, col_valid, &bias, 1.0 / tau),
    }
    Ok(())
}

fn row_softmax(m: &mut DenseMatrix, row_valid: Option<&[bool]>, bias: &[f32], it: f32) {
    let cols = m.cols;
    m.data
        .par_chunks_mut(cols)
        .enumerate()
        .with_min_len(rows_per_task(m.rows, cols, 1 << 15))
        .for_each(|(i, row)| {
            if row_valid.is_some_and(|r| !r[i]) {
                row.fill(0.0);
                return;
            }
            for (v, b) in row.iter_mut().zip(bias) {
                *v += b;
            }
            softmax_tail(row, it);
        });
}

/// Row softmax of the biased logits already in `row`.
#[inline(always)]
fn softmax_tail(row: &mut [f32], it: f32) {
    let mx = max_lanes(row);
    if mx == f32::NEG_INFINITY {
        row.fill(0.0);
        return;
    }
    for v in row.iter_mut() {
        *v = fast_exp((*v - mx) * it);
    }
    let inv = 1.0 / sum_lanes(row);
    for v in row.iter_mut() {
        *v *= inv;
    }
}

fn dual_softmax(
    m: &mut DenseMatrix,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
    bias: &[f32],
    it: f32,
) {
    let (rows, cols) = (m.rows, m.cols);
    let st = dual_stats(m, row_valid, col_valid, bias, it);
    // Pass 3: P = sqrt(Pr * Pc + eps), row by row.
    m.data
        .par_chunks_mut(cols)
        .enumerate()
        .with_min_len(rows_per_task(rows, cols, 1 << 15))
        .for_each(|(i, row)| st.row_in_place(i, row));
}

/// The row and column statistics of the dual softmax of `S / tau` (passes 1 and 2 of
/// [`calibrate`]'s dual softmax): with them any row of the calibrated matrix follows from that
/// row of `S` alone ([`DualStats::row_in_place`]), so the posterior inspector gets one row
/// without an N x M copy, computed by the same code as the whole matrix.
pub(crate) struct DualStats {
    row_ok: Vec<bool>,
    rmax: Vec<f32>,
    rlse: Vec<f32>,
    cmax_f: Vec<f32>,
    clse_f: Vec<f32>,
    cgate: Vec<f32>,
    it: f32,
}

impl DualStats {
    /// Row `i` of the dual softmax, in place on that row of the similarity.
    #[inline]
    pub(crate) fn row_in_place(&self, i: usize, row: &mut [f32]) {
        if !self.row_ok[i] || self.rmax[i] == f32::NEG_INFINITY {
            row.fill(0.0);
            return;
        }
        let it = self.it;
        let (a, la) = (self.rmax[i], self.rlse[i]);
        for (v, ((m, l), g)) in row
            .iter_mut()
            .zip(self.cmax_f.iter().zip(&self.clse_f).zip(&self.cgate))
        {
            let s = *v;
            let z = (s - a) * it - la + ((s - m) * it - l);
            *v = (fast_exp(z) + DUAL_SOFTMAX_EPS).sqrt() * g;
        }
    }
}

/// [`DualStats`] of `m` (masks as in [`calibrate`]); errors as [`calibrate`] does.
pub(crate) fn dual_stats_of(
    m: &DenseMatrix,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
    tau: f32,
) -> Result<DualStats> {
    check_masks("calibrate", m.rows, m.cols, row_valid, col_valid)?;
    if m.data.len() != m.rows * m.cols {
        return Err(Error::Shape(format!(
            "calibrate: matrix holds {} values, expected {} x {}",
            m.data.len(),
            m.rows,
            m.cols
        )));
    }
    if !(tau.is_finite() && tau > 0.0) {
        return Err(Error::Param(format!(
            "calibrate: temperature must be a positive finite number, found {tau}"
        )));
    }
    Ok(dual_stats(
        m,
        row_valid,
        col_valid,
        &col_bias(m.cols, col_valid),
        1.0 / tau,
    ))
}

/// Additive column bias: 0 for valid columns, -inf for invalid ones, so `s + bias` is the
/// masked logit without a branch in the inner loops.
fn col_bias(cols: usize, col_valid: Option<&[bool]>) -> Vec<f32> {
    match col_valid {
        Some(c) => c
            .iter()
            .map(|&v| if v { 0.0 } else { f32::NEG_INFINITY })
            .collect(),
        None => vec![0.0; cols],
    }
}

fn dual_stats(
    m: &DenseMatrix,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
    bias: &[f32],
    it: f32,
) -> DualStats {
    let (rows, cols) = (m.rows, m.cols);
    let band = rows_per_task(rows, cols, 1 << 18).max(1);
    let row_ok: Vec<bool> = (0..rows).map(|i| row_valid.is_none_or(|r| r[i])).collect();
    if cols == 0 {
        return DualStats {
            row_ok,
            rmax: vec![f32::NEG_INFINITY; rows],
            rlse: vec![0.0; rows],
            cmax_f: Vec::new(),
            clse_f: Vec::new(),
            cgate: Vec::new(),
            it,
        };
    }

    // Pass 1: row maxima and column maxima of the masked similarities.
    let mut rmax = vec![f32::NEG_INFINITY; rows];
    let cmax = m
        .data
        .par_chunks(band * cols)
        .zip(rmax.par_chunks_mut(band))
        .enumerate()
        .map(|(t, (chunk, rm))| {
            let mut cm = vec![f32::NEG_INFINITY; cols];
            for (k, (row, r)) in chunk.chunks(cols).zip(rm.iter_mut()).enumerate() {
                if !row_ok[t * band + k] {
                    continue;
                }
                for ((s, b), c) in row.iter().zip(bias).zip(cm.iter_mut()) {
                    let v = s + b;
                    *c = if v > *c { v } else { *c };
                }
                *r = max_plus(row, bias);
            }
            cm
        })
        .reduce_with(|mut a, b| {
            for (x, y) in a.iter_mut().zip(&b) {
                *x = x.max(*y);
            }
            a
        })
        .unwrap_or_else(|| vec![f32::NEG_INFINITY; cols]);

    // 1.0 for a column that is valid and has a valid entry, else 0.0 (forces exact zeros).
    let cgate: Vec<f32> = (0..cols)
        .map(|j| {
            let ok = col_valid.is_none_or(|c| c[j]) && cmax[j] > f32::NEG_INFINITY;
            if ok {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    // Invalid columns get finite stand-ins so the gated product stays 0, not NaN.
    let cmax_f: Vec<f32> = cmax
        .iter()
        .zip(&cgate)
        .map(|(&c, &g)| if g > 0.0 { c } else { 0.0 })
        .collect();

    // Pass 2: log of the row and column sums of exp((s - max) / tau).
    let mut rlse = vec![0.0f32; rows];
    let csum = m
        .data
        .par_chunks(band * cols)
        .zip(rlse.par_chunks_mut(band))
        .zip(rmax.par_chunks(band))
        .enumerate()
        .map(|(t, ((chunk, rl), rm))| {
            let mut cs = vec![0.0f32; cols];
            let mut scratch = vec![0.0f32; cols];
            for (k, row) in chunk.chunks(cols).enumerate() {
                if !row_ok[t * band + k] || rm[k] == f32::NEG_INFINITY {
                    continue;
                }
                let a = rm[k];
                for (((s, b), (e, c)), m) in row
                    .iter()
                    .zip(bias)
                    .zip(scratch.iter_mut().zip(cs.iter_mut()))
                    .zip(&cmax_f)
                {
                    let v = s + b;
                    *e = fast_exp((v - a) * it);
                    *c += fast_exp((v - m) * it);
                }
                rl[k] = sum_lanes(&scratch).ln();
            }
            cs
        })
        .reduce_with(|mut a, b| {
            for (x, y) in a.iter_mut().zip(&b) {
                *x += y;
            }
            a
        })
        .unwrap_or_else(|| vec![0.0; cols]);
    let clse_f: Vec<f32> = csum
        .iter()
        .zip(&cgate)
        .map(|(&c, &g)| if g > 0.0 { c.ln() } else { 0.0 })
        .collect();
    DualStats {
        row_ok,
        rmax,
        rlse,
        cmax_f,
        clse_f,
        cgate,
        it,
    }
}

/// Sum with 8 independent accumulators so the loop vectorises.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub(crate) fn sum_lanes(x: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let chunks = x.chunks_exact(8);
    let rem = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            acc[k] += c[k];
        }
    }
    acc.iter().sum::<f32>() + rem.iter().sum::<f32>()
}

/// max_j (row[j] + bias[j]) with 8 independent lanes.
#[inline]
#[allow(clippy::needless_range_loop)]
fn max_plus(row: &[f32], bias: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; 8];
    let mut m = f32::NEG_INFINITY;
    let (rc, bc) = (row.chunks_exact(8), bias.chunks_exact(8));
    for (v, w) in row[row.len() - rc.remainder().len()..]
        .iter()
        .zip(bc.remainder())
    {
        let x = v + w;
        m = if x > m { x } else { m };
    }
    for (r, b) in rc.zip(bc) {
        for k in 0..8 {
            let x = r[k] + b[k];
            acc[k] = if x > acc[k] { x } else { acc[k] };
        }
    }
    acc.iter().fold(m, |a, &b| if b > a { b } else { a })
}

/// Maximum with 8 independent lanes (NaN entries are ignored).
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub(crate) fn max_lanes(x: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; 8];
    let chunks = x.chunks_exact(8);
    let rem = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            acc[k] = if c[k] > acc[k] { c[k] } else { acc[k] };
        }
    }
    let mut m = f32::NEG_INFINITY;
    for &v in acc.iter().chain(rem) {
        m = if v > m { v } else { m };
    }
    m
}

/// exp(x) for f32, branch-free so it vectorises (Cephes `expf`: round x/ln2 to n, degree-6
/// polynomial on the remainder, scale by 2^n from the exponent bits). Relative error about
/// 2e-7; x below -87.34 (including -inf) gives exactly 0.
#[inline(always)]
pub(crate) fn fast_exp(x: f32) -> f32 {
    const LO: f32 = -87.336_54;
    const HI: f32 = 88.0;
    const MAGIC: f32 = 12_582_912.0; // 1.5 * 2^23: adding it rounds to an integer
    let xc = if x < LO { LO } else { x };
    let xc = if xc > HI { HI } else { xc };
    let t = xc * std::f32::consts::LOG2_E + MAGIC;
    let n = t - MAGIC;
    let r = xc - n * 0.693_359_4 + n * 2.121_944_4e-4;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    let y = p * (r * r) + r + 1.0;
    let ni = (t.to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32);
    let scale = f32::from_bits(((ni + 127) << 23) as u32);
    if x < LO {
        0.0
    } else {
        y * scale
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::testing::Lcg;

    fn random(rows: usize, cols: usize, seed: u64) -> DenseMatrix {
        let mut s = Lcg(seed);
        DenseMatrix::from_fn(rows, cols, |_, _| s.signed_f32()).unwrap()
    }

    #[test]
    fn fast_exp_is_accurate() {
        let mut x = -90.0f32;
        while x < 88.0 {
            let want = (x as f64).exp();
            let got = fast_exp(x) as f64;
            if want > 1.2e-38 {
                assert!(((got - want) / want).abs() < 4e-7, "x={x}: {got} vs {want}");
            }
            x += 0.0137;
        }
        assert_eq!(fast_exp(f32::NEG_INFINITY), 0.0);
        assert_eq!(fast_exp(-100.0), 0.0);
        assert_eq!(fast_exp(0.0), 1.0);
    }

    #[test]
    fn row_softmax_rows_sum_to_one_and_match_formula() {
        let sim = random(37, 53, 7);
        let tau = 0.1;
        let p = calibrate(&sim, None, None, Calibration::RowSoftmax { tau }).unwrap();
        for i in 0..sim.rows {
            let row = sim.row(i);
            let mx = row.iter().cloned().fold(f64::MIN, |a, b| a.max(b as f64));
            let z: f64 = row
                .iter()
                .map(|&s| ((s as f64 - mx) / tau as f64).exp())
                .sum();
            let total: f64 = p.row(i).iter().map(|&v| v as f64).sum();
            assert!((total - 1.0).abs() < 1e-5, "row {i} sums to {total}");
            for j in 0..sim.cols {
                let want = ((sim.get(i, j) as f64 - mx) / tau as f64).exp() / z;
                assert!(
                    (p.get(i, j) as f64 - want).abs() <= 1e-6 * want.max(1e-3),
                    "({i},{j})"
                );
            }
        }
    }

    #[test]
    fn row_softmax_with_masks() {
        let sim = random(20, 30, 8);
        let rv: Vec<bool> = (0..20).map(|i| i % 5 != 0).collect();
        let cv: Vec<bool> = (0..30).map(|j| j % 3 != 1).collect();
        let p = calibrate(
            &sim,
            Some(&rv),
            Some(&cv),
            Calibration::RowSoftmax { tau: 0.05 },
        )
        .unwrap();
        for i in 0..20 {
            let total: f32 = p.row(i).iter().sum();
            if rv[i] {
                assert!((total - 1.0).abs() < 1e-5);
            } else {
                assert_eq!(total, 0.0);
            }
            for j in 0..30 {
                if !cv[j] {
                    assert_eq!(p.get(i, j), 0.0);
                }
            }
        }
        // Large similarities must not overflow (max is subtracted first).
        let big = DenseMatrix::from_vec(1, 3, vec![1e4, 1e4 - 1.0, -1e4]).unwrap();
        let pb = calibrate(&big, None, None, Calibration::RowSoftmax { tau: 0.1 }).unwrap();
        assert!(pb.data.iter().all(|v| v.is_finite()));
        assert!((pb.get(0, 0) - 1.0 / (1.0 + (-10f32).exp())).abs() < 1e-6);
    }

    /// Direct transcription of the reference's `_prob_from_similarity(mode="rc_softmax")`, in f64.
    fn dual_brute(sim: &DenseMatrix, rv: &[bool], cv: &[bool], tau: f64) -> Vec<f64> {
        let (n, m) = (sim.rows, sim.cols);
        let valid = |i: usize, j: usize| rv[i] && cv[j];
        let z = |i: usize, j: usize| {
            if valid(i, j) {
                sim.get(i, j) as f64 / tau
            } else {
                f64::NEG_INFINITY
            }
        };
        let mut out = vec![0.0; n * m];
        for i in 0..n {
            for j in 0..m {
                if !valid(i, j) {
                    continue;
                }
                let rmax = (0..m).map(|q| z(i, q)).fold(f64::NEG_INFINITY, f64::max);
                let rs: f64 = (0..m).map(|q| (z(i, q) - rmax).exp()).sum();
                let cmax = (0..n).map(|q| z(q, j)).fold(f64::NEG_INFINITY, f64::max);
                let cs: f64 = (0..n).map(|q| (z(q, j) - cmax).exp()).sum();
                let pr = (z(i, j) - rmax).exp() / rs;
                let pc = (z(i, j) - cmax).exp() / cs;
                out[i * m + j] = (pr * pc + 1e-9).sqrt();
            }
        }
        out
    }

    #[test]
    fn dual_softmax_matches_brute_force_with_masks() {
        let (n, m) = (23, 31);
        let sim = random(n, m, 9);
        let rv: Vec<bool> = (0..n).map(|i| i % 4 != 2).collect();
        let cv: Vec<bool> = (0..m).map(|j| j % 5 != 3).collect();
        for tau in [0.1f32, 0.03, 1.0] {
            let p =
                calibrate(&sim, Some(&rv), Some(&cv), Calibration::DualSoftmax { tau }).unwrap();
            let want = dual_brute(&sim, &rv, &cv, tau as f64);
            for (k, (&g, &w)) in p.data.iter().zip(&want).enumerate() {
                if w == 0.0 {
                    assert_eq!(g, 0.0, "entry {k} should be masked");
                } else {
                    assert!(((g as f64 - w) / w).abs() < 2e-5, "entry {k}: {g} vs {w}");
                    assert!(g >= 3.1e-5);
                }
            }
        }
        // Unmasked equals all-true masks.
        let a = calibrate(&sim, None, None, Calibration::DualSoftmax { tau: 0.1 }).unwrap();
        let b = calibrate(
            &sim,
            Some(&vec![true; n]),
            Some(&vec![true; m]),
            Calibration::DualSoftmax { tau: 0.1 },
        )
        .unwrap();
        assert_eq!(a, b);
        // Nothing valid: all zero, no NaN.
        let z = calibrate(
            &sim,
            Some(&vec![false; n]),
            None,
            Calibration::DualSoftmax { tau: 0.1 },
        )
        .unwrap();
        assert!(z.data.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn bad_input_is_an_error() {
        let sim = random(4, 5, 1);
        assert!(calibrate(&sim, Some(&[true; 3]), None, Calibration::default()).is_err());
        assert!(calibrate(&sim, None, Some(&[true; 4]), Calibration::default()).is_err());
        assert!(calibrate(&sim, None, None, Calibration::RowSoftmax { tau: 0.0 }).is_err());
        assert!(calibrate(&sim, None, None, Calibration::DualSoftmax { tau: f32::NAN }).is_err());
        let empty = DenseMatrix::zeros(0, 5).unwrap();
        assert!(calibrate(&empty, None, None, Calibration::default())
            .unwrap()
            .is_empty());
    }
}
