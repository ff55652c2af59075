//! Picking in the 3D viewport: the correspondence line or point under the pointer, the
//! click that selects it, and the readout next to the pointer.

use eframe::egui;
use nalgebra::{Isometry3, Matrix4};

use super::measure::{Cloud, Picked};
use super::scene::ScreenSegment;
use super::{apply, iso_to_mat, point3, View3dState};
use crate::app::state::Shared;

/// Hovering a correspondence line marks it; a click selects the hovered line, else the
/// source point under the pointer.
pub(super) fn pointer_picking(
    response: &egui::Response,
    shared: &mut Shared<'_>,
    state: &mut View3dState,
    segments: &[ScreenSegment],
    src_xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
) {
    if let Some(pos) = response.hover_pos() {
        let best = segments
            .iter()
            .map(|(mi, a, b)| (*mi, point_segment_distance(pos, *a, *b)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((mi, d)) = best {
            if d < 5.0 && state.prefs.show_lines {
                shared.ui.hovered_match = Some(mi);
            }
        }
    }
    if response.clicked() && state.measure.active {
        // the distance tool takes the click: the source point under it, else the target's
        if let Some(pos) = response.interact_pointer_pos() {
            if let Some(p) = point_under(state, src_xf, vp, rect, pos, 10.0) {
                state.measure.pick(p);
            }
        }
        return;
    }
    if response.clicked() {
        if let Some(mi) = shared.ui.hovered_match {
            shared.select_match(mi);
        } else if let Some(pos) = response.interact_pointer_pos() {
            if let Some(i) = pick_point(&state.source_pos, src_xf, vp, rect, pos, 10.0) {
                shared.select_source_point(i);
            }
        }
    }
}

/// What is under the pointer: the hovered match (its keypoints, fused score and its rank
/// quantile, its residual under the drawn pose, GT and estimator verdicts), else the source
/// or target point there (its index, and its match when it has one).
pub(super) fn hover_readout(
    shared: &Shared<'_>,
    state: &View3dState,
    src_xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
    pos: egui::Pos2,
) -> Option<String> {
    let model = shared.model;
    let describe = |mi: usize| -> Option<String> {
        let m = model.matches.get(mi)?;
        let (s, t) = (model.source.get(m.src)?, model.target.get(m.tgt)?);
        let pose = model.estimated.unwrap_or(model.initial);
        let d = (point3(apply(&pose, *s)) - point3(*t)).norm();
        let q = model.score_quantiles().get(mi).copied().unwrap_or(0.0);
        Some(format!(
            "match #{mi}: source point {} -> target point {}\nfused score {:.4} (rank quantile {:.2}) · {}\nresidual under the estimate {:.1} cm · {} · {}",
            m.src,
            m.tgt,
            m.score,
            q,
            m.branch.label(),
            d * 100.0,
            match m.inlier_gt {
                Some(true) => "GT inlier",
                Some(false) => "GT outlier",
                None => "GT unknown",
            },
            match m.survived {
                Some(true) => "kept by the estimator",
                Some(false) => "rejected by the estimator",
                None => "not estimated",
            }
        ))
    };
    if let Some(mi) = shared.ui.hovered_match {
        return describe(mi);
    }
    let p = point_under(state, src_xf, vp, rect, pos, 6.0)?;
    let (who, i) = (p.cloud.label(), p.index);
    let matched = match p.cloud {
        Cloud::Source => model.matches.iter().position(|m| m.src == i),
        Cloud::Target => model.matches.iter().position(|m| m.tgt == i),
    };
    let kind = if matched.is_some() {
        "keypoint"
    } else {
        "point"
    };
    Some(match matched.and_then(describe) {
        Some(m) => format!("{who} {kind} {i}\n{m}"),
        None => format!("{who} {kind} {i} (no correspondence)"),
    })
}

/// The point under `pos` within `radius` pixels: a source point (drawn under `src_xf`) first,
/// else a target point when the target is shown.
fn point_under(
    state: &View3dState,
    src_xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
    pos: egui::Pos2,
    radius: f32,
) -> Option<Picked> {
    if let Some(index) = pick_point(&state.source_pos, src_xf, vp, rect, pos, radius) {
        return Some(Picked {
            cloud: Cloud::Source,
            index,
        });
    }
    if !state.prefs.show_target {
        return None;
    }
    let xf = Isometry3::identity();
    let index = pick_point(&state.target_pos, &xf, vp, rect, pos, radius)?;
    Some(Picked {
        cloud: Cloud::Target,
        index,
    })
}

/// A small text box beside the pointer, kept inside the viewport.
pub(super) fn readout_box(painter: &egui::Painter, pos: egui::Pos2, rect: egui::Rect, text: &str) {
    let galley = painter.layout_no_wrap(
        text.to_string(),
        egui::FontId::proportional(12.0),
        egui::Color32::from_gray(235),
    );
    let size = galley.size() + egui::vec2(12.0, 8.0);
    let mut at = pos + egui::vec2(16.0, 16.0);
    if at.x + size.x > rect.right() {
        at.x = pos.x - 16.0 - size.x;
    }
    if at.y + size.y > rect.bottom() {
        at.y = pos.y - 16.0 - size.y;
    }
    let r = egui::Rect::from_min_size(at, size);
    painter.rect_filled(r, 4.0, egui::Color32::from_black_alpha(210));
    painter.galley(at + egui::vec2(6.0, 4.0), galley, egui::Color32::WHITE);
}

fn point_segment_distance(p: egui::Pos2, a: egui::Pos2, b: egui::Pos2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_sq().max(1e-6)).clamp(0.0, 1.0);
    (a + ab * t - p).length()
}

/// The source point nearest to `pos` on screen within `radius` pixels.
pub(super) fn pick_point(
    pts: &[[f32; 3]],
    xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
    pos: egui::Pos2,
    radius: f32,
) -> Option<usize> {
    let m = vp * iso_to_mat(xf);
    let (w, h) = (rect.width(), rect.height());
    let local = pos - rect.min;
    let mut best: Option<(usize, f32, f32)> = None;
    for (i, p) in pts.iter().enumerate() {
        let c = m * nalgebra::Vector4::new(p[0], p[1], p[2], 1.0);
        if c.w <= 1e-6 {
            continue;
        }
        let x = (c.x / c.w + 1.0) * 0.5 * w;
        let y = (1.0 - c.y / c.w) * 0.5 * h;
        let d2 = (x - local.x).powi(2) + (y - local.y).powi(2);
        if d2 <= radius * radius {
            let z = c.z / c.w;
            // prefer the nearest to the camera among those under the cursor
            if best.is_none_or(|b| z < b.2 - 1e-4 || (d2 < b.1 && (z - b.2).abs() < 1e-4)) {
                best = Some((i, d2, z));
            }
        }
    }
    best.map(|b| b.0)
}
