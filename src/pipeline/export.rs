//! The selected correspondences of one registration as a table, and that table as an `.npz`
//! (`cgenreg register --export-corr FILE.npz` and the inspector's "Export correspondences..."
//! both call [`export_correspondences`]).
//!
//! Every array has one row per selected correspondence, in the pipeline's order (fused score
//! descending). All arrays are float64 so that cgenreg's own NPY reader (floats only) reads the
//! file back: indices are exact (below 2^53), flags are 0 / 1 and NaN means "not available".
//!
//! | entry | shape | meaning |
//! |---|---|---|
//! | `src_idx`, `tgt_idx` | (n,) | index into the source / target **keypoints** (the voxel-downsampled clouds the geometric branch used) |
//! | `src_xyz`, `tgt_xyz` | (n, 3) | those keypoints, each in its own scan frame (m) |
//! | `fused` | (n,) | the score the selection ranked by (fused posterior; a single-branch mode: that branch's posterior) |
//! | `p_img`, `p_geo` | (n,) | the image / geometric posterior of the pair; NaN where that branch did not contribute (branch off, not part of the fusion mode, or a keypoint without a pixel) |
//! | `branch` | (n,) | which branch proposed the match: 1 image, 2 geometry, 3 both, 0 neither (the fused score alone); a branch proposes (i, j) when j is the most likely target of i under its posterior |
//! | `inlier_est` | (n,) | residual under the estimate below `inlier_threshold_m` |
//! | `inlier_gt` | (n,) | the same under the ground truth; NaN without ground truth |
//! | `kept_by_estimator` | (n,) | in the estimator's own inlier set (its own threshold) |
//! | `residual_est_m`, `residual_gt_m` | (n,) | the residuals behind the two flags (NaN without GT) |
//! | `target_from_source`, `gt_target_from_source` | (4, 4) | the estimate, the ground truth (NaN without GT) |
//!
//! `meta.json` (a zip member that is not an array: `np.load(f)["meta.json"]` gives its bytes)
//! holds the pair, the parameters, the code version, the threshold and the codes above.

use super::params::RegisterParams;
use super::result::RegistrationResult;
use super::tail::{similarities, FusionInputs, Similarities};
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::fusion::{FusionMode, PosteriorRows};
use nalgebra::{Isometry3, Point3};
use std::path::Path;

/// Which branch proposed a correspondence (the `branch` code of the export).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProposedBy {
    /// Neither branch's most likely target: selected by the fused score alone.
    Neither = 0,
    Image = 1,
    Geometry = 2,
    Both = 3,
}

impl ProposedBy {
    fn of(image: bool, geometry: bool) -> Self {
        match (image, geometry) {
            (true, true) => ProposedBy::Both,
            (true, false) => ProposedBy::Image,
            (false, true) => ProposedBy::Geometry,
            (false, false) => ProposedBy::Neither,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            ProposedBy::Neither => "neither",
            ProposedBy::Image => "image",
            ProposedBy::Geometry => "geometry",
            ProposedBy::Both => "both",
        }
    }
}

/// The selected correspondences with everything the export writes (see the module docs).
#[derive(Clone, Debug)]
pub struct CorrespondenceTable {
    pub src_idx: Vec<u32>,
    pub tgt_idx: Vec<u32>,
    pub src_xyz: Vec<Point3<f32>>,
    pub tgt_xyz: Vec<Point3<f32>>,
    pub fused: Vec<f32>,
    /// NaN where the branch did not contribute.
    pub p_img: Vec<f32>,
    pub p_geo: Vec<f32>,
    pub branch: Vec<ProposedBy>,
    pub residual_est_m: Vec<f64>,
    pub inlier_est: Vec<bool>,
    /// None without ground truth.
    pub residual_gt_m: Option<Vec<f64>>,
    pub inlier_gt: Option<Vec<bool>>,
    pub kept_by_estimator: Vec<bool>,
    pub inlier_threshold_m: f64,
    pub target_from_source: Isometry3<f64>,
    pub gt_target_from_source: Option<Isometry3<f64>>,
    /// `meta.json`: pair, parameters, code version, threshold, codes.
    pub meta: serde_json::Value,
}

impl CorrespondenceTable {
    pub fn len(&self) -> usize {
        self.src_idx.len()
    }
    pub fn is_empty(&self) -> bool {
        self.src_idx.is_empty()
    }
}

/// The argmax of a row (first maximum; None for an empty or all-NaN row).
fn argmax(v: &[f32]) -> Option<usize> {
    let mut best: Option<(usize, f32)> = None;
    for (j, &x) in v.iter().enumerate() {
        if !x.is_nan() && best.is_none_or(|(_, b)| x > b) {
            best = Some((j, x));
        }
    }
    best.map(|(j, _)| j)
}

/// The table of `res`'s selected correspondences. `inputs` and `params` must be those `res`
/// was computed from (the posteriors are recomputed row by row with the same code that
/// selected the matches: [`PosteriorRows`]); `sims` are the kept similarities, None computes
/// them. Threshold of both inlier flags: `params.inlier_threshold_m()`.
pub fn correspondence_table(
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    res: &RegistrationResult,
) -> Result<CorrespondenceTable> {
    let (sk, tk) = (
        &inputs.source_geo.keypoints.points,
        &inputs.target_geo.keypoints.points,
    );
    if sk.len() != res.source_keypoints.len() || tk.len() != res.target_keypoints.len() {
        return Err(Error::Shape(format!(
            "export: the fusion inputs have {} / {} keypoints, the result {} / {}",
            sk.len(),
            tk.len(),
            res.source_keypoints.len(),
            res.target_keypoints.len()
        )));
    }
    let computed;
    let sims = match sims {
        Some(s) => s,
        None => {
            computed = similarities(inputs)?;
            &computed
        }
    };
    let mut fusion = params.fusion;
    if inputs.image.is_none() {
        // as fuse_and_finish: without image descriptors only geometry-only fusion runs
        fusion.mode = FusionMode::GeometryOnly;
    }
    if matches!(fusion.mode, FusionMode::Union | FusionMode::Visibility) && inputs.image.is_some() {
        // the union's pairs carry Noisy-AND's posterior (those only in the geometric set: 0)
        fusion.mode = FusionMode::NoisyAnd;
    }
    let img = sims
        .image
        .as_ref()
        .map(|(s, vs, vt)| (s, Some(vs.as_slice()), Some(vt.as_slice())));
    let rows = PosteriorRows::new(img, Some(&sims.geo), &fusion)?;
    let img_used = img.is_some() && fusion.mode != FusionMode::GeometryOnly;
    let geo_used = fusion.mode != FusionMode::ImageOnly;
    let (row_ok, col_ok) = match &sims.image {
        Some((_, vs, vt)) => (vs.clone(), vt.clone()),
        None => (Vec::new(), Vec::new()),
    };

    let n = res.correspondences.len();
    let mut t = CorrespondenceTable {
        src_idx: Vec::with_capacity(n),
        tgt_idx: Vec::with_capacity(n),
        src_xyz: Vec::with_capacity(n),
        tgt_xyz: Vec::with_capacity(n),
        fused: Vec::with_capacity(n),
        p_img: Vec::with_capacity(n),
        p_geo: Vec::with_capacity(n),
        branch: Vec::with_capacity(n),
        residual_est_m: Vec::with_capacity(n),
        inlier_est: Vec::with_capacity(n),
        residual_gt_m: pair.gt_target_from_source.map(|_| Vec::with_capacity(n)),
        inlier_gt: pair.gt_target_from_source.map(|_| Vec::with_capacity(n)),
        kept_by_estimator: vec![false; n],
        inlier_threshold_m: params.inlier_threshold_m(),
        target_from_source: res.estimate,
        gt_target_from_source: pair.gt_target_from_source,
        meta: serde_json::Value::Null,
    };
    for &i in &res.inliers {
        if let Some(k) = t.kept_by_estimator.get_mut(i) {
            *k = true;
        }
    }
    // Rows are computed once per source point (a row holds every target's posterior).
    let mut row_cache: Option<(usize, crate::fusion::PosteriorRow)> = None;
    for c in &res.correspondences {
        let (i, j) = (c.src as usize, c.tgt as usize);
        let (sp, tp) = match (sk.get(i), tk.get(j)) {
            (Some(s), Some(t)) => (*s, *t),
            _ => {
                return Err(Error::Shape(format!(
                    "export: correspondence {i} -> {j} is outside the keypoints ({} / {})",
                    sk.len(),
                    tk.len()
                )))
            }
        };
        let row = match &row_cache {
            Some((r, row)) if *r == i => row,
            _ => &row_cache.insert((i, rows.row(i)?)).1,
        };
        let img_valid =
            row_ok.get(i).copied().unwrap_or(false) && col_ok.get(j).copied().unwrap_or(false);
        let p_img = match &row.image {
            Some(r) if img_used && img_valid => r[j],
            _ => f32::NAN,
        };
        let p_geo = match &row.geometric {
            Some(r) if geo_used => r[j],
            _ => f32::NAN,
        };
        let by_img = img_used && img_valid && row.image.as_deref().and_then(argmax) == Some(j);
        let by_geo = geo_used && row.geometric.as_deref().and_then(argmax) == Some(j);
        let (s64, t64) = (sp.cast::<f64>(), tp.cast::<f64>());
        let r_est = (res.estimate * s64 - t64).norm();
        t.src_idx.push(c.src);
        t.tgt_idx.push(c.tgt);
        t.src_xyz.push(sp);
        t.tgt_xyz.push(tp);
        t.fused.push(c.score);
        t.p_img.push(p_img);
        t.p_geo.push(p_geo);
        t.branch.push(ProposedBy::of(by_img, by_geo));
        t.residual_est_m.push(r_est);
        t.inlier_est.push(r_est < params.inlier_threshold_m());
        if let (Some(gt), Some(rg), Some(ig)) = (
            pair.gt_target_from_source.as_ref(),
            t.residual_gt_m.as_mut(),
            t.inlier_gt.as_mut(),
        ) {
            let r = (gt * s64 - t64).norm();
            rg.push(r);
            ig.push(r < params.inlier_threshold_m());
        }
    }
    t.meta = serde_json::json!({
        "format": "cgenreg correspondences v1",
        "code_version": super::shard::code_version(),
        "pair_id": res.pair_id,
        "source_name": res.source_name,
        "target_name": res.target_name,
        "indices_into": "keypoints: the voxel-downsampled source / target clouds the geometric branch used (src_idx into the source keypoints, tgt_idx into the target keypoints); src_xyz / tgt_xyz are those points in their own scan frames",
        "n_source_keypoints": sk.len(),
        "n_target_keypoints": tk.len(),
        "n_correspondences": n,
        "inlier_threshold_m": params.inlier_threshold_m(),
        "inlier_est": "residual |T_est * src_xyz - tgt_xyz| < inlier_threshold_m",
        "inlier_gt": "residual |T_gt * src_xyz - tgt_xyz| < inlier_threshold_m (NaN: no ground truth)",
        "kept_by_estimator": "in the estimator's own inlier set (its own threshold)",
        "branch_codes": {"0": "neither (fused score alone)", "1": "image", "2": "geometry", "3": "both"},
        "branch_rule": "a branch proposes (i, j) when j is the argmax of its posterior row i",
        "p_img_p_geo": "branch posteriors; NaN where the branch did not contribute (off, not in the fusion mode, or no pixel)",
        "fusion_mode_used": format!("{:?}", fusion.mode),
        "estimator": res.estimator,
        "image_branch": res.image_branch,
        "geo_features": res.geo_features,
        "dtypes": "every array is float64 (indices exact; flags 0/1; NaN = not available)",
        "params": serde_json::to_value(params).unwrap_or(serde_json::Value::Null),
    });
    Ok(t)
}

fn flat3(v: &[Point3<f32>]) -> Vec<f64> {
    v.iter()
        .flat_map(|p| [p.x as f64, p.y as f64, p.z as f64])
        .collect()
}

fn flags(v: &[bool]) -> Vec<f64> {
    v.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect()
}

fn matrix(m: Option<&Isometry3<f64>>) -> Vec<f64> {
    match m {
        Some(m) => {
            let h = m.to_homogeneous();
            (0..4)
                .flat_map(|r| (0..4).map(move |c| h[(r, c)]))
                .collect()
        }
        None => vec![f64::NAN; 16],
    }
}

/// The `.npz` entries of `t` (see the module docs), `meta.json` last.
pub fn npz_entries(t: &CorrespondenceTable) -> Result<Vec<(String, Vec<u8>)>> {
    use crate::io::npy::encode_npy_f64;
    let n = t.len();
    let col = |name: &str, v: Vec<f64>| (format!("{name}.npy"), encode_npy_f64(&[n], &v));
    let nan = || vec![f64::NAN; n];
    let f32s = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
    let mut e = vec![
        col("src_idx", t.src_idx.iter().map(|&i| i as f64).collect()),
        col("tgt_idx", t.tgt_idx.iter().map(|&i| i as f64).collect()),
        (
            "src_xyz.npy".into(),
            encode_npy_f64(&[n, 3], &flat3(&t.src_xyz)),
        ),
        (
            "tgt_xyz.npy".into(),
            encode_npy_f64(&[n, 3], &flat3(&t.tgt_xyz)),
        ),
        col("fused", f32s(&t.fused)),
        col("p_img", f32s(&t.p_img)),
        col("p_geo", f32s(&t.p_geo)),
        col("branch", t.branch.iter().map(|&b| b as u8 as f64).collect()),
        col("inlier_est", flags(&t.inlier_est)),
        col(
            "inlier_gt",
            t.inlier_gt.as_deref().map(flags).unwrap_or_else(nan),
        ),
        col("kept_by_estimator", flags(&t.kept_by_estimator)),
        col("residual_est_m", t.residual_est_m.clone()),
        col("residual_gt_m", t.residual_gt_m.clone().unwrap_or_else(nan)),
        (
            "target_from_source.npy".into(),
            encode_npy_f64(&[4, 4], &matrix(Some(&t.target_from_source))),
        ),
        (
            "gt_target_from_source.npy".into(),
            encode_npy_f64(&[4, 4], &matrix(t.gt_target_from_source.as_ref())),
        ),
    ];
    let meta = serde_json::to_vec_pretty(&t.meta)
        .map_err(|e| Error::Encode(format!("export: serialising meta.json: {e}")))?;
    e.push(("meta.json".into(), meta));
    Ok(e)
}

/// [`correspondence_table`] written to `path` as an `.npz` through the output guard
/// ([`crate::io::output::write`]: atomic, never through a link or over a device; a file
/// cgenreg did not write only with `force`). Returns the table.
pub fn export_correspondences(
    path: &Path,
    force: bool,
    pair: &ScanPair,
    params: &RegisterParams,
    inputs: &FusionInputs,
    sims: Option<&Similarities>,
    res: &RegistrationResult,
) -> Result<CorrespondenceTable> {
    use crate::io::output::{write, OutputKind};
    let t = correspondence_table(pair, params, inputs, sims, res)?;
    let bytes = crate::io::npy::encode_npz(&npz_entries(&t)?)?;
    write(path, OutputKind::Npz, force, &bytes)?;
    Ok(t)
}
