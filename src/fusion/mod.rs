//! Match-then-Fuse: similarities, calibration into correspondence posteriors, fusion and
//! correspondence selection (paper §3 "Modality Correspondence Posterior" to "Transformation
//! Estimation"; reference §8).
//!
//! Memory: a dense N x M f32 matrix is used only for the two posteriors and the fused scores
//! (never N x M x K^2: view pairs are reduced by an element-wise max as they are computed).
//! [`FusionOutput::peak_bytes`] accounts for those matrices. Every such matrix is within the
//! dense-matrix budget ([`matrix::budget_bytes`]; an error above it, never an abort). Geometry
//! alone with row NN ([`streaming`]) and the paper's configuration from features
//! ([`match_then_fuse_select_features`]) hold no N x M matrix at all.

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
pub mod calibrate;
pub mod fuse;
mod fused;
pub mod posterior;
pub mod select;
pub mod similarity;
pub mod streaming;
pub mod union;

pub use crate::matrix::DenseMatrix;
pub use calibrate::{calibrate, calibrate_in_place, Calibration};
pub use fuse::{concat_features, concat_similarity, fuse, noisy_and, noisy_or, FusionMode};
pub use posterior::{posterior_row, PosteriorRow, PosteriorRows};
pub use select::{select, Selection};
pub use similarity::{cosine_similarity, max_similarity};

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// One putative correspondence: source point index, target point index, and its score
/// (the fused posterior, or the single-branch posterior).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    pub src: u32,
    pub tgt: u32,
    pub score: f32,
}

/// Everything that turns two similarity matrices into correspondences.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FusionParams {
    pub calibration_img: Calibration,
    pub calibration_geo: Calibration,
    pub mode: FusionMode,
    /// Prior match probability pi; None = 1 / (N M) (paper and reference).
    pub prior: Option<f64>,
    pub selection: Selection,
    /// Use the reference code's float32 fusion formula instead of the stable one.
    pub exact_reference: bool,
    /// Image weight w of the concatenation baseline (cosine = w cos_img + (1 - w) cos_geo).
    pub concat_w_img: f32,
}

impl Default for FusionParams {
    /// The paper: row softmax with tau = 0.1 per branch, Noisy-AND, mutual nearest neighbours.
    fn default() -> Self {
        FusionParams {
            calibration_img: Calibration::RowSoftmax { tau: 0.1 },
            calibration_geo: Calibration::RowSoftmax { tau: 0.1 },
            mode: FusionMode::NoisyAnd,
            prior: None,
            selection: Selection::MutualNn,
            exact_reference: false,
            concat_w_img: 0.5,
        }
    }
}

impl FusionParams {
    /// These parameters with `mode` replaced by the mode whose matrix it selects from
    /// ([`FusionMode::matrix_mode`]).
    pub fn matrix_params(mut self) -> Self {
        self.mode = self.mode.matrix_mode();
        self
    }

    /// The authors' code: dual softmax with T = 0.1, float32 Noisy-AND, global top-8000.
    pub fn reference() -> Self {
        FusionParams {
            calibration_img: Calibration::DualSoftmax { tau: 0.1 },
            calibration_geo: Calibration::DualSoftmax { tau: 0.1 },
            mode: FusionMode::NoisyAnd,
            prior: None,
            selection: Selection::TopK(select::REFERENCE_TOP_K),
            exact_reference: true,
            concat_w_img: 0.5,
        }
    }
}

/// The correspondences with the posteriors they came from (kept for the posterior inspector).
#[derive(Clone, Debug, PartialEq)]
pub struct FusionOutput {
    /// Sorted by (score descending, source, target); scores are fused posteriors.
    pub correspondences: Vec<Correspondence>,
    pub p_img: Option<DenseMatrix>,
    pub p_geo: Option<DenseMatrix>,
    /// The fused posterior (for `Concat`, the calibrated similarity of the concatenation).
    pub fused: DenseMatrix,
    /// Bytes of the dense matrices this call held at once.
    pub peak_bytes: usize,
}

/// The image-branch similarity with its source (row) and target (column) validity.
pub type ImageSimilarity<'a> = (&'a DenseMatrix, Option<&'a [bool]>, Option<&'a [bool]>);

/// A similarity matrix must hold exactly rows x cols values.
fn check_filled(what: &str, m: &DenseMatrix) -> Result<()> {
    if m.data.len() != m.rows * m.cols {
        return Err(Error::Shape(format!(
            "match-then-fuse: {what} similarity holds {} values, expected {} x {}",
            m.data.len(),
            m.rows,
            m.cols
        )));
    }
    Ok(())
}

/// Calibrates the given branch similarities, fuses them per `params.mode` and selects
/// correspondences. `sim_img` carries the image branch's row (source) and column (target)
/// validity: entry (i, j) is valid iff both points have a pixel. The geometric branch is valid
/// everywhere. `Concat` uses `calibration_geo` for the concatenated similarity.
pub fn match_then_fuse(
    sim_img: Option<ImageSimilarity<'_>>,
    sim_geo: Option<&DenseMatrix>,
    params: &FusionParams,
) -> Result<FusionOutput> {
    let params = &params.matrix_params();
    let shape = match (sim_img, sim_geo) {
        (Some((a, _, _)), Some(b)) if a.shape() != b.shape() => {
            return Err(Error::Shape(format!(
                "match-then-fuse: image similarity is {} x {}, geometric similarity is {} x {}",
                a.rows, a.cols, b.rows, b.cols
            )))
        }
        (Some((a, _, _)), _) => a.shape(),
        (None, Some(b)) => b.shape(),
        (None, None) => {
            return Err(Error::Missing(
                "match-then-fuse: no similarity given".into(),
            ))
        }
    };
    for (what, m) in [("image", sim_img.map(|s| s.0)), ("geometric", sim_geo)] {
        if let Some(m) = m {
            check_filled(what, m)?;
        }
    }
    if let Some((_, rv, cv)) = sim_img {
        crate::matrix::check_masks("match-then-fuse image validity", shape.0, shape.1, rv, cv)?;
    }
    let needs_img = !matches!(params.mode, FusionMode::GeometryOnly);
    let needs_geo = !matches!(params.mode, FusionMode::ImageOnly);
    if needs_img && sim_img.is_none() || needs_geo && sim_geo.is_none() {
        return Err(Error::Missing(format!(
            "match-then-fuse: fusion mode {:?} needs {}",
            params.mode,
            match (
                needs_img && sim_img.is_none(),
                needs_geo && sim_geo.is_none()
            ) {
                (true, true) => "both similarities",
                (true, false) => "the image similarity",
                _ => "the geometric similarity",
            }
        )));
    }

    // The paper's default configuration in one pass (same results as the general path).
    if let Some((a, b)) = one_pass_branches(sim_img, sim_geo, params) {
        let out = fused::row_softmax_noisy_and(&a, &b, params.prior, params.selection, true)?;
        let (p_img, p_geo, fused) = out.mats.ok_or_else(missing)?;
        let peak_bytes = p_img.bytes() + p_geo.bytes() + fused.bytes();
        return Ok(FusionOutput {
            correspondences: out.correspondences,
            p_img: Some(p_img),
            p_geo: Some(p_geo),
            fused,
            peak_bytes,
        });
    }
    let p_img = sim_img
        .map(|(s, rv, cv)| calibrate(s, rv, cv, params.calibration_img))
        .transpose()?;
    let p_geo = sim_geo
        .map(|s| calibrate(s, None, None, params.calibration_geo))
        .transpose()?;
    let held =
        p_img.as_ref().map_or(0, DenseMatrix::bytes) + p_geo.as_ref().map_or(0, DenseMatrix::bytes);

    let (fused, correspondences) = match params.mode {
        FusionMode::NoisyAnd if !params.exact_reference => {
            // Rank by the non-saturating odds key, then turn the keys into posteriors in place.
            let (a, b) = (p_img.as_ref(), p_geo.as_ref());
            let (a, b) = (a.ok_or_else(missing)?, b.ok_or_else(missing)?);
            let mut fused = fuse::noisy_and_rank_keys(a, b)?;
            let mut corr = select(&fused, params.selection);
            fuse::rank_keys_to_posteriors(&mut fused, params.prior)?;
            for c in &mut corr {
                c.score = fused.get(c.src as usize, c.tgt as usize);
            }
            (fused, corr)
        }
        FusionMode::Concat => {
            let ((si, rv, cv), sg) = (sim_img.ok_or_else(missing)?, sim_geo.ok_or_else(missing)?);
            let mut s = concat_similarity(si, rv, cv, sg, params.concat_w_img)?;
            calibrate_in_place(&mut s, None, None, params.calibration_geo)?;
            let corr = select(&s, params.selection);
            (s, corr)
        }
        mode => {
            let fused = fuse(
                p_img.as_ref(),
                p_geo.as_ref(),
                mode,
                params.prior,
                params.exact_reference,
            )?;
            let corr = select(&fused, params.selection);
            (fused, corr)
        }
    };
    let peak_bytes = held + fused.bytes();
    Ok(FusionOutput {
        correspondences,
        p_img,
        p_geo,
        fused,
        peak_bytes,
    })
}

/// The branches of the configuration [`fused`] handles in one pass: both similarities, row
/// softmax for both, stable Noisy-AND, mutual or row nearest neighbours.
fn one_pass_branches<'a>(
    sim_img: Option<ImageSimilarity<'a>>,
    sim_geo: Option<&'a DenseMatrix>,
    params: &FusionParams,
) -> Option<(fused::Branch<'a>, fused::Branch<'a>)> {
    match (
        sim_img,
        sim_geo,
        params.calibration_img,
        params.calibration_geo,
        params.mode,
        params.exact_reference,
        params.selection,
    ) {
        (
            Some((si, rv, cv)),
            Some(sg),
            Calibration::RowSoftmax { tau: ta },
            Calibration::RowSoftmax { tau: tg },
            FusionMode::NoisyAnd,
            false,
            Selection::MutualNn | Selection::RowNn,
        ) => Some((
            fused::Branch {
                sim: fused::Sim::Dense(si),
                row_valid: rv,
                col_valid: cv,
                tau: ta,
            },
            fused::Branch {
                sim: fused::Sim::Dense(sg),
                row_valid: None,
                col_valid: None,
                tau: tg,
            },
        )),
        _ => None,
    }
}

/// The correspondences [`match_then_fuse`] selects (identical, same order and scores),
/// without returning the posterior matrices. For the paper's default configuration (row
/// softmax, Noisy-AND, mutual or row nearest neighbours) no N x M matrix is formed at all:
/// memory is O(N + M) and the inputs are read once. Other configurations fall back to
/// [`match_then_fuse`].
pub fn match_then_fuse_select(
    sim_img: Option<ImageSimilarity<'_>>,
    sim_geo: Option<&DenseMatrix>,
    params: &FusionParams,
) -> Result<Vec<Correspondence>> {
    let params = &params.matrix_params();
    if let (Some((a, _, _)), Some(b)) = (sim_img, sim_geo) {
        check_filled("image", a)?;
        check_filled("geometric", b)?;
        if let Some((_, rv, cv)) = sim_img {
            crate::matrix::check_masks("match-then-fuse image validity", a.rows, a.cols, rv, cv)?;
        }
    }
    if let Some(a) = image_only_branch(sim_img, sim_geo, params)? {
        return Ok(fused::row_softmax_image_only(&a, params.selection)?.correspondences);
    }
    match one_pass_branches(sim_img, sim_geo, params) {
        Some((a, b)) => {
            Ok(
                fused::row_softmax_noisy_and(&a, &b, params.prior, params.selection, false)?
                    .correspondences,
            )
        }
        None => Ok(match_then_fuse(sim_img, sim_geo, params)?.correspondences),
    }
}

/// The image branch of the image-only configuration [`fused`] handles in one pass (row
/// softmax, mutual or row nearest neighbours), its inputs checked as [`match_then_fuse`]
/// checks them; None for any other configuration. The general path would calibrate both
/// branches and copy the image posterior before selecting from it (same correspondences).
fn image_only_branch<'a>(
    sim_img: Option<ImageSimilarity<'a>>,
    sim_geo: Option<&DenseMatrix>,
    params: &FusionParams,
) -> Result<Option<fused::Branch<'a>>> {
    let (
        FusionMode::ImageOnly,
        Calibration::RowSoftmax { tau },
        Selection::MutualNn | Selection::RowNn,
        false,
        Some((si, rv, cv)),
    ) = (
        params.mode,
        params.calibration_img,
        params.selection,
        params.exact_reference,
        sim_img,
    )
    else {
        return Ok(None);
    };
    if let Some(g) = sim_geo {
        let geo_tau = params.calibration_geo.tau();
        if g.shape() != si.shape() || !(geo_tau.is_finite() && geo_tau > 0.0) {
            // the general path's error (it calibrates the geometric branch too)
            return Ok(None);
        }
        check_filled("geometric", g)?;
    }
    check_filled("image", si)?;
    crate::matrix::check_masks("match-then-fuse image validity", si.rows, si.cols, rv, cv)?;
    Ok(Some(fused::Branch {
        sim: fused::Sim::Dense(si),
        row_valid: rv,
        col_valid: cv,
        tau,
    }))
}

/// Whether [`match_then_fuse_select_features`] handles `params` without N x M matrices: the
/// configurations of [`fused`]: row softmax, mutual or row nearest neighbours, and stable
/// Noisy-AND (row softmax for the geometric branch too) or the image branch alone.
pub fn streams_from_features(params: &FusionParams) -> bool {
    let params = &params.matrix_params();
    let nn = matches!(params.selection, Selection::MutualNn | Selection::RowNn);
    let img = matches!(params.calibration_img, Calibration::RowSoftmax { .. });
    let geo = matches!(params.calibration_geo, Calibration::RowSoftmax { .. });
    nn && img
        && !params.exact_reference
        && match params.mode {
            FusionMode::NoisyAnd => geo,
            FusionMode::ImageOnly => true,
            _ => false,
        }
}

/// Per-point image descriptors with their validity: (source, valid, target, valid).
pub type ImageFeatures<'a> = (
    &'a crate::features::Features,
    &'a [bool],
    &'a crate::features::Features,
    &'a [bool],
);

/// [`match_then_fuse_select`] on the features instead of the similarity matrices: the same
/// correspondences (same order and scores: each band of similarity rows is formed as
/// [`cosine_similarity`] forms it), and no N x M matrix is ever held (memory O(N + M) per
/// task plus one band of rows per branch). `None` when `params` is not the configuration it
/// handles ([`streams_from_features`]): the caller forms the matrices.
pub fn match_then_fuse_select_features(
    image: ImageFeatures<'_>,
    geo: (&crate::features::Features, &crate::features::Features),
    params: &FusionParams,
) -> Result<Option<Vec<Correspondence>>> {
    if !streams_from_features(params) {
        return Ok(None);
    }
    let params = &params.matrix_params();
    let tau = |c: Calibration| match c {
        Calibration::RowSoftmax { tau } => tau,
        _ => f32::NAN,
    };
    let (fs, vs, ft, vt) = image;
    let (n, m) = (fs.len(), ft.len());
    if geo.0.len() != n || geo.1.len() != m {
        return Err(Error::Shape(format!(
            "fusion: image features for {n} x {m} points, geometric features for {} x {}",
            geo.0.len(),
            geo.1.len()
        )));
    }
    for (what, f) in [
        ("source image", fs),
        ("target image", ft),
        ("source geometric", geo.0),
        ("target geometric", geo.1),
    ] {
        if f.dim > 0 && f.data.len() % f.dim != 0 {
            return Err(Error::Shape(format!(
                "fusion: {what} features hold {} values, not a multiple of {}",
                f.data.len(),
                f.dim
            )));
        }
    }
    crate::matrix::check_masks("match-then-fuse image validity", n, m, Some(vs), Some(vt))?;
    if n == 0 || m == 0 {
        return Ok(Some(Vec::new()));
    }
    // n, m > 0: every side has dim > 0 (`Features::len` is 0 otherwise)
    let (is, it) = (
        similarity::normalize_rows(fs),
        similarity::normalize_rows(ft),
    );
    let (gs, gt) = (
        similarity::normalize_rows(geo.0),
        similarity::normalize_rows(geo.1),
    );
    let (it, gt) = (similarity::DotRhs::new(&it), similarity::DotRhs::new(&gt));
    let img_sim = fused::Sim::Features { src: &is, tgt: &it };
    let geo_sim = fused::Sim::Features { src: &gs, tgt: &gt };
    let a = fused::Branch {
        sim: img_sim,
        row_valid: Some(vs),
        col_valid: Some(vt),
        tau: tau(params.calibration_img),
    };
    if params.mode == FusionMode::ImageOnly {
        return Ok(Some(
            fused::row_softmax_image_only(&a, params.selection)?.correspondences,
        ));
    }
    let b = fused::Branch {
        sim: geo_sim,
        row_valid: None,
        col_valid: None,
        tau: tau(params.calibration_geo),
    };
    Ok(Some(
        fused::row_softmax_noisy_and(&a, &b, params.prior, params.selection, false)?
            .correspondences,
    ))
}

fn missing() -> Error {
    Error::Missing("match-then-fuse: a branch posterior is missing".into())
}

#[cfg(test)]
mod tests;
