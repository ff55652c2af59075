//! Per-point colours of the clouds under a colour mode, display normals, and match colours.

use std::sync::Arc;

use nalgebra::Point3;

use super::{apply, point3, rgba, CloudColorMode, OCCLUDED_RGB, VISIBLE_RGB};
use crate::app::colormap::{self, NEUTRAL_RGB, SOURCE_RGB, TARGET_RGB};
use crate::app::model::{Branch, InspectorModel};
use crate::app::state::MatchColorMode;
use crate::geometry::knn::KdIndex;

/// Per-point display normals of one cloud (shared with the GL thread).
pub(super) type DisplayNormals = Arc<Vec<[f32; 3]>>;

/// Unoriented unit normals for shading (local PCA over the 16 nearest points within four
/// point spacings; zero where degenerate), from the library's normal estimation.
pub fn display_normals(pts: &[[f32; 3]]) -> Vec<[f32; 3]> {
    if pts.len() < 3 {
        return vec![[0.0; 3]; pts.len()];
    }
    let p: Vec<Point3<f32>> = pts.iter().map(|q| point3(*q)).collect();
    let index = KdIndex::new(&p);
    // the spacing: median distance to the nearest other point over a sample
    let step = (p.len() / 256).max(1);
    let mut d: Vec<f32> = p
        .iter()
        .step_by(step)
        .filter_map(|q| index.knn(q, 2).get(1).map(|x| x.1))
        .collect();
    d.sort_by(f32::total_cmp);
    let spacing = d.get(d.len() / 2).copied().unwrap_or(0.01).max(1e-4);
    crate::geometry::normals::estimate_normals(&p, &index, 4.0 * spacing as f64, 16)
        .into_iter()
        .map(|n| [n.x, n.y, n.z])
        .collect()
}

/// Whether a mode colours by a continuous scale (a colour bar goes with it).
pub fn is_scalar(mode: CloudColorMode) -> bool {
    matches!(
        mode,
        CloudColorMode::FusedScore
            | CloudColorMode::ResidualEstimate
            | CloudColorMode::ResidualGroundTruth
    )
}

/// The fixed colour of a cloud: grey while the other cloud shows a colour map.
pub fn fixed_rgb(is_source: bool, other_scalar: bool) -> [u8; 3] {
    match (is_source, other_scalar) {
        (_, true) => NEUTRAL_RGB,
        (true, false) => SOURCE_RGB,
        (false, false) => TARGET_RGB,
    }
}

/// Per-point colours of a cloud under a colour mode; `other_scalar`: the other cloud shows a
/// colour map (a fixed colour then turns grey).
pub fn cloud_colors(
    model: &InspectorModel,
    is_source: bool,
    mode: CloudColorMode,
    other_scalar: bool,
) -> Vec<[u8; 4]> {
    let pts = if is_source {
        &model.source
    } else {
        &model.target
    };
    let base = fixed_rgb(is_source, other_scalar || is_scalar(mode));
    let dim = |c: [u8; 3]| rgba([c[0] / 3 + 40, c[1] / 3 + 40, c[2] / 3 + 40]);
    match mode {
        CloudColorMode::Fixed => vec![rgba(base); pts.len()],
        CloudColorMode::Visibility => {
            let views = if is_source {
                &model.source_views
            } else {
                &model.target_views
            };
            // Best state over the views: visible beats occluded beats outside.
            let mut state = vec![None::<u8>; pts.len()];
            for v in views.iter().filter(|v| v.point_state.len() == pts.len()) {
                for (s, &x) in state.iter_mut().zip(&v.point_state) {
                    *s = Some(s.map_or(x, |y| y.max(x)));
                }
            }
            state
                .into_iter()
                .map(|s| match s {
                    Some(2) => rgba(VISIBLE_RGB),
                    Some(1) => rgba(OCCLUDED_RGB),
                    Some(_) => dim(base),
                    None => rgba([128, 128, 128]),
                })
                .collect()
        }
        CloudColorMode::FusedScore | CloudColorMode::Branch => {
            let mut out = vec![dim(base); pts.len()];
            let q = model.score_quantiles();
            for (m, &q) in model.matches.iter().zip(&q) {
                let i = if is_source { m.src } else { m.tgt };
                if i < out.len() {
                    out[i] = rgba(if mode == CloudColorMode::FusedScore {
                        colormap::turbo(q)
                    } else {
                        branch_rgb(m.branch)
                    });
                }
            }
            out
        }
        CloudColorMode::ResidualEstimate | CloudColorMode::ResidualGroundTruth => {
            let t = if mode == CloudColorMode::ResidualEstimate {
                model.estimated
            } else {
                model.ground_truth
            };
            let Some(t) = t else {
                return vec![rgba([128, 128, 128]); pts.len()];
            };
            let (from, to, xf) = if is_source {
                (&model.source, &model.target, t)
            } else {
                (&model.target, &model.source, t.inverse())
            };
            let index = KdIndex::new(&to.iter().map(|p| point3(*p)).collect::<Vec<_>>());
            let cap = super::residual_cap_m(model);
            use rayon::prelude::*;
            from.par_iter()
                .map(|p| {
                    // no point in the other cloud: as far as the colormap goes
                    let d = index
                        .nearest(&point3(apply(&xf, *p)))
                        .map_or(cap, |(_, d)| d.min(cap));
                    rgba(colormap::turbo(d / cap))
                })
                .collect()
        }
    }
}

pub fn branch_rgb(b: Branch) -> [u8; 3] {
    match b {
        Branch::Image => [255, 80, 220],
        Branch::Geometry => [40, 230, 230],
        Branch::Both => [255, 255, 255],
    }
}

/// Colour of a shown match under the chosen colour mode (`rank` is its index in the shown set;
/// `quantiles`: [`InspectorModel::score_quantiles`], the confidence colours' scale).
pub fn match_rgb(
    model: &InspectorModel,
    idx: usize,
    rank: usize,
    mode: MatchColorMode,
    quantiles: &[f32],
) -> [u8; 3] {
    let m = &model.matches[idx];
    match mode {
        MatchColorMode::Categorical => colormap::categorical(rank),
        MatchColorMode::InlierOutlier => match m.inlier_gt {
            Some(true) => colormap::INLIER_RGB,
            Some(false) => colormap::OUTLIER_RGB,
            None => [160, 160, 160],
        },
        MatchColorMode::Confidence => colormap::turbo(quantiles.get(idx).copied().unwrap_or(0.0)),
    }
}
