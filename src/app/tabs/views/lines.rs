//! The matches between the two images: which fall in a view pair, their lines, hover,
//! highlight, tooltip and the click that opens the Posterior tab.

use eframe::egui;

use super::image::{to_screen_win, Layout};
use crate::app::colormap::{to_color32, HIGHLIGHT_RGB};
use crate::app::model::{InspectorModel, ViewImage};
use crate::app::state::{Panel, Shared};
use crate::app::view3d::match_rgb;

/// Per view pair (row-major, `source_views.len()` x `target_views.len()`): how many of the
/// `shown` matches have their source endpoint visible in source view i and their target
/// endpoint visible in target view j. A match seen by several views counts in each pair.
pub fn pair_counts(model: &InspectorModel, shown: &[usize]) -> Vec<usize> {
    let (ks, kt) = (model.source_views.len(), model.target_views.len());
    let mut counts = vec![0; ks * kt];
    let seen = |v: &ViewImage, mi: usize| v.match_pixels.get(mi).copied().flatten().is_some();
    for &mi in shown {
        for (i, sv) in model.source_views.iter().enumerate() {
            if !seen(sv, mi) {
                continue;
            }
            for (j, tv) in model.target_views.iter().enumerate() {
                if seen(tv, mi) {
                    counts[i * kt + j] += 1;
                }
            }
        }
    }
    counts
}

/// The view pair with the most matches (the first such in row-major order).
pub fn best_pair(counts: &[usize], kt: usize) -> (usize, usize) {
    let best = counts
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(&a.0)))
        .map_or(0, |(i, _)| i);
    (best / kt.max(1), best % kt.max(1))
}

/// The `shown` matches (with their rank in the shown set) drawn in view pair (`sv`, `tv`),
/// and their pixels there: exactly those visible in both views.
pub fn matches_in_pair(
    sv: &ViewImage,
    tv: &ViewImage,
    shown: &[usize],
) -> Vec<(usize, usize, [f32; 2], [f32; 2])> {
    shown
        .iter()
        .enumerate()
        .filter_map(|(rank, &mi)| {
            let a = sv.match_pixels.get(mi).copied().flatten()?;
            let b = tv.match_pixels.get(mi).copied().flatten()?;
            Some((rank, mi, a, b))
        })
        .collect()
}

fn point_segment_distance(p: egui::Pos2, a: egui::Pos2, b: egui::Pos2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_sq().max(1e-6)).clamp(0.0, 1.0);
    (a + ab * t - p).length()
}

/// A drawn match on screen: (match index, source end, target end).
pub(super) type Segment = (usize, egui::Pos2, egui::Pos2);

/// One line per match of the pair; with a zoom, those with an end outside the window are
/// left out (a line to an unseen point would cross the other image). Returns the drawn ones.
pub(super) fn match_lines(
    painter: &egui::Painter,
    shared: &Shared<'_>,
    layout: &Layout,
    win: egui::Rect,
    (sv, tv): (&ViewImage, &ViewImage),
    in_pair: &[(usize, usize, [f32; 2], [f32; 2])],
) -> Vec<Segment> {
    let (rs, rt) = (layout.rs, layout.rt);
    let mut segs = Vec::with_capacity(in_pair.len());
    let quantiles = shared.model.score_quantiles();
    let style = shared.ui.line_style;
    let dot = (style.width + 1.0).max(2.2);
    for &(rank, mi, a, b) in in_pair {
        let (pa, pb) = (
            to_screen_win(rs, win, &sv.rgb, a),
            to_screen_win(rt, win, &tv.rgb, b),
        );
        if !(rs.contains(pa) && rt.contains(pb)) {
            continue;
        }
        let c = to_color32(match_rgb(
            shared.model,
            mi,
            rank,
            shared.ui.match_mode,
            &quantiles,
        ));
        let c = c.linear_multiply(style.alpha);
        painter.line_segment([pa, pb], egui::Stroke::new(style.width, c));
        painter.circle_filled(pa, dot, c);
        painter.circle_filled(pb, dot, c);
        segs.push((mi, pa, pb));
    }
    segs
}

/// The pointer near a line or an endpoint marks that match as hovered.
pub(super) fn hover_match(response: &egui::Response, segs: &[Segment], shared: &mut Shared<'_>) {
    if let Some(pos) = response.hover_pos() {
        let best = segs
            .iter()
            .map(|(mi, a, b)| {
                let d = point_segment_distance(pos, *a, *b)
                    .min((pos - *a).length() - 2.0)
                    .min((pos - *b).length() - 2.0);
                (*mi, d)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((mi, d)) = best {
            if d < 5.0 {
                shared.ui.hovered_match = Some(mi);
            }
        }
    }
}

/// The highlighted match, and the selected source point's pixel in the source view.
pub(super) fn highlights(
    painter: &egui::Painter,
    shared: &Shared<'_>,
    segs: &[Segment],
    layout: &Layout,
    win: egui::Rect,
    sv: &ViewImage,
) {
    let hc = to_color32(HIGHLIGHT_RGB);
    if let Some(mi) = shared.highlight() {
        if let Some((_, pa, pb)) = segs.iter().find(|s| s.0 == mi) {
            painter.line_segment([*pa, *pb], egui::Stroke::new(3.0, hc));
            painter.circle_stroke(*pa, 6.0, egui::Stroke::new(2.0, hc));
            painter.circle_stroke(*pb, 6.0, egui::Stroke::new(2.0, hc));
        }
    }
    if let Some(sp) = shared.ui.selected_source_point {
        if let Some(mi) = shared.model.matches.iter().position(|m| m.src == sp) {
            if let Some(a) = sv.match_pixels.get(mi).copied().flatten() {
                let p = to_screen_win(layout.rs, win, &sv.rgb, a);
                if layout.rs.contains(p) {
                    painter.circle_stroke(p, 8.0, egui::Stroke::new(2.0, egui::Color32::WHITE));
                }
            }
        }
    }
}

/// The hovered match's indices, score, branch and GT status next to the pointer.
pub(super) fn hover_tooltip(
    painter: &egui::Painter,
    shared: &Shared<'_>,
    response: &egui::Response,
) {
    let (Some(mi), Some(pos)) = (shared.ui.hovered_match, response.hover_pos()) else {
        return;
    };
    let Some(m) = shared.model.matches.get(mi) else {
        return;
    };
    let gt = match m.inlier_gt {
        Some(true) => "GT inlier",
        Some(false) => "GT outlier",
        None => "GT unknown",
    };
    let text = format!(
        "#{mi}: src {} -> tgt {} · score {:.2} · {} · {gt} · click: posterior",
        m.src,
        m.tgt,
        m.score,
        m.branch.label()
    );
    let at = pos + egui::vec2(12.0, -18.0);
    let galley =
        painter.layout_no_wrap(text, egui::FontId::proportional(12.0), egui::Color32::WHITE);
    let bg = egui::Rect::from_min_size(at, galley.size()).expand(3.0);
    painter.rect_filled(bg, 3.0, egui::Color32::from_black_alpha(200));
    painter.galley(at, galley, egui::Color32::WHITE);
}

/// A click on a match (or near a source endpoint) selects it and opens the Posterior tab.
pub(super) fn click_opens_posterior(
    response: &egui::Response,
    segs: &[Segment],
    shared: &mut Shared<'_>,
) {
    if !response.clicked() {
        return;
    }
    if let Some(mi) = shared.ui.hovered_match.or_else(|| {
        // a click near a source endpoint picks that match
        let pos = response.interact_pointer_pos()?;
        segs.iter()
            .map(|(mi, a, _)| (*mi, (*a - pos).length()))
            .filter(|x| x.1 < 15.0)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|x| x.0)
    }) {
        shared.select_match(mi);
        shared.ui.tab = Panel::Posterior;
    }
}
