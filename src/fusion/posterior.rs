//! One row of Match-then-Fuse's posteriors: the image, geometric and fused posterior of one
//! source point over every target point, as [`match_then_fuse`](super::match_then_fuse)
//! computes them for the whole matrix (same calibration, fusion and prior code; tested equal
//! row by row for every calibration and fusion mode). The posterior inspector calls this, so
//! the posterior a user inspects is the one that selected the correspondences.
//!
//! Cost: a row softmax needs only row `i`; a dual softmax needs its column statistics, one
//! read-only pass over the whole similarity (no N x M copy); concatenation with a dual softmax
//! forms the concatenated similarity (one N x M matrix), as `match_then_fuse` does.

use super::calibrate::{calibrate_in_place, dual_stats_of, Calibration, DualStats};
use super::fuse::{
    concat_similarity, default_prior, fuse_into, noisy_and_rank_keys, rank_keys_to_posteriors,
    FusionMode,
};
use super::{FusionParams, ImageSimilarity};
use crate::matrix::{check_masks, DenseMatrix};
use crate::{Error, Result};

/// The posteriors of one source point over all target points.
#[derive(Clone, Debug, PartialEq)]
pub struct PosteriorRow {
    /// The image-branch posterior (None without the image similarity).
    pub image: Option<Vec<f32>>,
    /// The geometric-branch posterior (None without the geometric similarity).
    pub geometric: Option<Vec<f32>>,
    /// The fused posterior (for `Concat`, the calibrated similarity of the concatenation;
    /// for one-branch modes, that branch's posterior).
    pub fused: Vec<f32>,
}

/// One branch's similarity with what its calibration needs beyond row `i` (the column
/// statistics of a dual softmax, computed once).
struct Calibrated<'a> {
    sim: &'a DenseMatrix,
    row_valid: Option<&'a [bool]>,
    col_valid: Option<&'a [bool]>,
    cal: Calibration,
    dual: Option<DualStats>,
}

impl<'a> Calibrated<'a> {
    fn new(
        sim: &'a DenseMatrix,
        row_valid: Option<&'a [bool]>,
        col_valid: Option<&'a [bool]>,
        cal: Calibration,
    ) -> Result<Self> {
        check_masks("posterior row", sim.rows, sim.cols, row_valid, col_valid)?;
        let dual = match cal {
            Calibration::RowSoftmax { .. } => None,
            Calibration::DualSoftmax { tau } => {
                Some(dual_stats_of(sim, row_valid, col_valid, tau)?)
            }
        };
        Ok(Calibrated {
            sim,
            row_valid,
            col_valid,
            cal,
            dual,
        })
    }

    /// Row `i` of the matrix [`calibrate`](super::calibrate) makes of the whole similarity.
    fn row(&self, i: usize) -> Result<Vec<f32>> {
        let mut row = DenseMatrix::from_vec(1, self.sim.cols, self.sim.row(i).to_vec())?;
        match &self.dual {
            None => {
                // A row softmax of row i depends on row i only.
                let rv = self.row_valid.map(|r| [r[i]]);
                calibrate_in_place(
                    &mut row,
                    rv.as_ref().map(|r| &r[..]),
                    self.col_valid,
                    self.cal,
                )?;
            }
            Some(st) => st.row_in_place(i, &mut row.data),
        }
        Ok(row.data)
    }
}

/// The image, geometric and fused posterior of source point `i`: row `i` of the matrices
/// [`match_then_fuse`](super::match_then_fuse) returns for the same inputs and parameters
/// (`p_img`, `p_geo`, `fused`). Errors as `match_then_fuse` does, and when `i` is not a row.
/// For many rows use [`PosteriorRows`] (a dual softmax's column statistics once).
pub fn posterior_row(
    sim_img: Option<ImageSimilarity<'_>>,
    sim_geo: Option<&DenseMatrix>,
    params: &FusionParams,
    i: usize,
) -> Result<PosteriorRow> {
    PosteriorRows::new(sim_img, sim_geo, params)?.row(i)
}

/// Rows of Match-then-Fuse's posteriors, one at a time, with everything that does not
/// depend on the row (a dual softmax's column statistics, a concatenated similarity under a
/// dual softmax) computed once by [`PosteriorRows::new`]. Memory: O(N + M) beyond the
/// similarities, except concatenation with a dual softmax (one N x M matrix, as
/// `match_then_fuse` forms).
pub struct PosteriorRows<'a> {
    sim_img: Option<ImageSimilarity<'a>>,
    sim_geo: Option<&'a DenseMatrix>,
    params: FusionParams,
    rows: usize,
    cols: usize,
    image: Option<Calibrated<'a>>,
    geometric: Option<Calibrated<'a>>,
    /// The concatenated similarity (Concat with a dual softmax) and its column statistics.
    concat_dual: Option<(DenseMatrix, DualStats)>,
}

impl<'a> PosteriorRows<'a> {
    /// Checks the inputs as [`match_then_fuse`](super::match_then_fuse) does.
    pub fn new(
        sim_img: Option<ImageSimilarity<'a>>,
        sim_geo: Option<&'a DenseMatrix>,
        params: &FusionParams,
    ) -> Result<Self> {
        let (rows, cols) = match (sim_img, sim_geo) {
            (Some((a, _, _)), Some(b)) if a.shape() != b.shape() => {
                return Err(Error::Shape(format!(
                    "posterior row: image similarity is {} x {}, geometric similarity is {} x {}",
                    a.rows, a.cols, b.rows, b.cols
                )))
            }
            (Some((a, _, _)), _) => a.shape(),
            (None, Some(b)) => b.shape(),
            (None, None) => {
                return Err(Error::Missing("posterior row: no similarity given".into()))
            }
        };
        for (what, m) in [("image", sim_img.map(|s| s.0)), ("geometric", sim_geo)] {
            if let Some(m) = m {
                if m.data.len() != m.rows * m.cols {
                    return Err(Error::Shape(format!(
                        "posterior row: {what} similarity holds {} values, expected {} x {}",
                        m.data.len(),
                        m.rows,
                        m.cols
                    )));
                }
            }
        }
        let image = sim_img
            .map(|(s, rv, cv)| Calibrated::new(s, rv, cv, params.calibration_img))
            .transpose()?;
        let geometric = sim_geo
            .map(|s| Calibrated::new(s, None, None, params.calibration_geo))
            .transpose()?;
        let concat_dual = match (params.mode, params.calibration_geo, sim_img, sim_geo) {
            (
                FusionMode::Concat,
                Calibration::DualSoftmax { tau },
                Some((si, rv, cv)),
                Some(sg),
            ) => {
                let s = concat_similarity(si, rv, cv, sg, params.concat_w_img)?;
                // match_then_fuse calibrates the concatenation without masks
                let st = dual_stats_of(&s, None, None, tau)?;
                Some((s, st))
            }
            _ => None,
        };
        Ok(PosteriorRows {
            sim_img,
            sim_geo,
            params: params.matrix_params(),
            rows,
            cols,
            image,
            geometric,
            concat_dual,
        })
    }

    /// Number of source points (rows).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Row `i`: as [`posterior_row`] with the same inputs.
    pub fn row(&self, i: usize) -> Result<PosteriorRow> {
        let (rows, cols, params) = (self.rows, self.cols, &self.params);
        // `new` stored the matrix mode: Union shows Noisy-AND's posterior
        if i >= rows {
            return Err(Error::Shape(format!(
                "posterior row: source point {i} out of range (the similarity has {rows} rows)"
            )));
        }
        let image = self.image.as_ref().map(|c| c.row(i)).transpose()?;
        let geometric = self.geometric.as_ref().map(|c| c.row(i)).transpose()?;
        let need = |p: &Option<Vec<f32>>, what: &str| {
            p.clone().ok_or_else(|| {
                Error::Missing(format!(
                    "posterior row: fusion mode {:?} needs the {what} similarity",
                    params.mode
                ))
            })
        };
        // The prior of the whole matrix, not of a 1 x M row.
        let prior = params.prior.unwrap_or_else(|| default_prior(rows, cols));
        let as_row = |v: Vec<f32>| DenseMatrix::from_vec(1, cols, v);
        let fused = match params.mode {
            FusionMode::ImageOnly => need(&image, "image")?,
            FusionMode::GeometryOnly => need(&geometric, "geometric")?,
            FusionMode::NoisyAnd | FusionMode::Union | FusionMode::Visibility
                if !params.exact_reference =>
            {
                let (a, b) = (
                    as_row(need(&image, "image")?)?,
                    as_row(need(&geometric, "geometric")?)?,
                );
                let mut keys = noisy_and_rank_keys(&a, &b)?;
                rank_keys_to_posteriors(&mut keys, Some(prior))?;
                keys.data
            }
            mode @ (FusionMode::NoisyAnd
            | FusionMode::NoisyOr
            | FusionMode::Union
            | FusionMode::Visibility) => {
                let (a, b) = (
                    as_row(need(&image, "image")?)?,
                    as_row(need(&geometric, "geometric")?)?,
                );
                let mut out = DenseMatrix::zeros(1, cols)?;
                let m = mode.matrix_mode();
                fuse_into(&mut out, &a, &b, m, Some(prior), params.exact_reference)?;
                out.data
            }
            FusionMode::Concat => {
                let ((si, rv, cv), sg) = match (self.sim_img, self.sim_geo) {
                    (Some(a), Some(b)) => (a, b),
                    _ => {
                        return Err(Error::Missing(
                            "posterior row: fusion mode Concat needs both similarities".into(),
                        ))
                    }
                };
                match &self.concat_dual {
                    None => {
                        // Entry (i, j) of the concatenated similarity depends on row i only.
                        let a = as_row(si.row(i).to_vec())?;
                        let b = as_row(sg.row(i).to_vec())?;
                        let rvi = rv.map(|r| [r[i]]);
                        let mut s = concat_similarity(
                            &a,
                            rvi.as_ref().map(|r| &r[..]),
                            cv,
                            &b,
                            params.concat_w_img,
                        )?;
                        calibrate_in_place(&mut s, None, None, params.calibration_geo)?;
                        s.data
                    }
                    Some((s, st)) => {
                        let mut row = s.row(i).to_vec();
                        st.row_in_place(i, &mut row);
                        row
                    }
                }
            }
        };
        Ok(PosteriorRow {
            image,
            geometric,
            fused,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::rng::seeded_for_test;
    use crate::fusion::{match_then_fuse, Selection};

    fn close(a: &[f32], b: &[f32], what: &str) -> std::result::Result<(), String> {
        if a.len() != b.len() {
            return Err(format!("{what}: lengths {} vs {}", a.len(), b.len()));
        }
        for (j, (x, y)) in a.iter().zip(b).enumerate() {
            let tol = 1e-6 * x.abs().max(y.abs()).max(1e-30) + 1e-12;
            if (x - y).abs() > tol && !(x.is_nan() && y.is_nan()) {
                return Err(format!("{what}[{j}]: row {x} vs matrix {y}"));
            }
        }
        Ok(())
    }

    /// Every row equals the matching row of `match_then_fuse`'s matrices, for every fusion
    /// mode, both calibrations per branch, both fusion formulas, given and default priors and
    /// the selections that take the one-pass and the general path; with masked rows/columns.
    #[test]
    fn every_row_equals_match_then_fuse() {
        let (seed, mut rng) = seeded_for_test("posterior-row");
        let (n, m) = (23, 31);
        // Similar structure to real data: a planted match per row plus noise in [-1, 1].
        let perm: Vec<usize> = (0..n).map(|i| (i * 7 + 3) % m).collect();
        let mut sim = |signal: f32| {
            DenseMatrix::from_fn(n, m, |i, j| {
                let noise = (rng.unit_f64() as f32 * 2.0 - 1.0) * 0.5;
                (noise + if perm[i] == j { signal } else { 0.0 }).clamp(-1.0, 1.0)
            })
            .unwrap()
        };
        let (s_img, s_geo) = (sim(0.6), sim(0.4));
        let rv: Vec<bool> = (0..n).map(|i| i % 5 != 2).collect();
        let cv: Vec<bool> = (0..m).map(|j| j % 7 != 4).collect();
        let mut checked = 0;
        for mode in FusionMode::ALL {
            for ci in Calibration::all_with_tau(0.1) {
                for cg in Calibration::all_with_tau(0.07) {
                    for exact_reference in [false, true] {
                        for prior in [None, Some(0.01)] {
                            for selection in [Selection::MutualNn, Selection::TopK(40)] {
                                let p = FusionParams {
                                    calibration_img: ci,
                                    calibration_geo: cg,
                                    mode,
                                    prior,
                                    selection,
                                    exact_reference,
                                    concat_w_img: 0.3,
                                };
                                let img = Some((&s_img, Some(&rv[..]), Some(&cv[..])));
                                let out = match_then_fuse(img, Some(&s_geo), &p).unwrap();
                                for i in 0..n {
                                    let r = posterior_row(img, Some(&s_geo), &p, i).unwrap();
                                    let ctx = format!("seed {seed}, {p:?}, row {i}");
                                    let pi = out.p_img.as_ref().unwrap();
                                    let pg = out.p_geo.as_ref().unwrap();
                                    close(r.image.as_ref().unwrap(), pi.row(i), "image")
                                        .and_then(|_| {
                                            close(r.geometric.as_ref().unwrap(), pg.row(i), "geo")
                                        })
                                        .and_then(|_| close(&r.fused, out.fused.row(i), "fused"))
                                        .unwrap_or_else(|e| panic!("{ctx}: {e}"));
                                    checked += 1;
                                }
                            }
                        }
                    }
                }
            }
        }
        assert_eq!(checked, FusionMode::ALL.len() * 2 * 2 * 2 * 2 * 2 * n);
    }

    #[test]
    fn geometry_only_without_image_and_bad_input() {
        let (_, mut rng) = seeded_for_test("posterior-row-geo");
        let s = DenseMatrix::from_fn(9, 12, |_, _| rng.unit_f64() as f32).unwrap();
        for cal in Calibration::all_with_tau(0.1) {
            let p = FusionParams {
                calibration_geo: cal,
                mode: FusionMode::GeometryOnly,
                ..FusionParams::default()
            };
            let out = match_then_fuse(None, Some(&s), &p).unwrap();
            for i in 0..9 {
                let r = posterior_row(None, Some(&s), &p, i).unwrap();
                assert!(r.image.is_none());
                close(&r.fused, out.fused.row(i), "fused").unwrap();
                let sum: f32 = r.geometric.unwrap().iter().sum();
                if matches!(cal, Calibration::RowSoftmax { .. }) {
                    assert!((sum - 1.0).abs() < 1e-5, "{sum}");
                }
            }
            assert!(posterior_row(None, Some(&s), &p, 9).is_err());
        }
        let p = FusionParams::default();
        assert!(
            posterior_row(None, Some(&s), &p, 0).is_err(),
            "Noisy-AND needs the image"
        );
        assert!(posterior_row(None, None, &p, 0).is_err());
    }
}
