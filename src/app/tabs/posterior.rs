//! Posterior inspector: the image, geometric and fused posteriors of one source point over
//! the target points, as heat maps on the target view and as colours of the target cloud.

use std::sync::Arc;

use eframe::egui;
use serde::{Deserialize, Serialize};

use super::views::{image_in_rect, to_screen, ViewsState};
use super::{Tab, TabContext};
use crate::app::colormap::{to_color32, turbo, TARGET_RGB};
use crate::app::model::{InspectorModel, Posterior};
use crate::app::state::{Panel, Shared};
use crate::app::view3d::legend::{color_bar, ColorBar};
use crate::app::view3d::{self, TargetOverride, View3dState};
use crate::geometry::knn::KdIndex;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PosteriorKind {
    Image,
    Geometric,
    Fused,
    /// Image minus geometric (normalised): where the branches disagree.
    Disagreement,
}

impl PosteriorKind {
    pub const ALL: [PosteriorKind; 4] = [
        Self::Image,
        Self::Geometric,
        Self::Fused,
        Self::Disagreement,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Self::Image => "image branch",
            Self::Geometric => "geometric branch",
            Self::Fused => "fused",
            Self::Disagreement => "disagreement (image - geometry)",
        }
    }
}

#[derive(Default)]
pub struct PosteriorTab {
    pub kind3d: Option<PosteriorKind>,
    pub view3d: View3dState,
    colors_key: Option<(u64, usize, PosteriorKind)>,
    colors: Option<(u64, Arc<Vec<[u8; 4]>>)>,
}

/// Values in [0, 1] (or [-1, 1] for disagreement) per candidate.
pub fn normalised(p: &Posterior, kind: PosteriorKind) -> Vec<f32> {
    let norm = |v: &[f32]| {
        let m = v.iter().cloned().fold(0.0f32, f32::max).max(1e-12);
        v.iter().map(|x| x / m).collect::<Vec<f32>>()
    };
    match kind {
        PosteriorKind::Image => norm(&p.image),
        PosteriorKind::Geometric => norm(&p.geometric),
        PosteriorKind::Fused => norm(&p.fused),
        PosteriorKind::Disagreement => {
            let (a, b) = (norm(&p.image), norm(&p.geometric));
            a.iter().zip(&b).map(|(x, y)| x - y).collect()
        }
    }
}

/// Colour of a normalised value; disagreement uses magenta (image) vs cyan (geometry).
pub fn value_rgb(v: f32, kind: PosteriorKind) -> [u8; 3] {
    if kind == PosteriorKind::Disagreement {
        let a = v.abs().clamp(0.0, 1.0);
        let base = 40.0;
        if v >= 0.0 {
            [
                (base + a * 215.0) as u8,
                base as u8,
                (base + a * 200.0) as u8,
            ]
        } else {
            [
                base as u8,
                (base + a * 215.0) as u8,
                (base + a * 215.0) as u8,
            ]
        }
    } else {
        turbo(v)
    }
}

/// A candidate counts as the ground truth within the run's inlier threshold.
/// Whether target point `cand` is where the ground truth puts source point `src` (within the
/// run's GT inlier distance): the test a match's GT inlier flag uses, so a match and its
/// argmax are never called both "fails under GT" and "at GT". None without ground truth.
fn near_gt(model: &InspectorModel, src: usize, cand: usize) -> Option<bool> {
    let g = model.ground_truth?;
    let (s, t) = (model.source.get(src)?, model.target.get(cand)?);
    let p = g.cast::<f32>() * nalgebra::Point3::new(s[0], s[1], s[2]);
    let d = (p - nalgebra::Point3::new(t[0], t[1], t[2])).norm();
    Some(f64::from(d) <= model.gt_inlier_m)
}

fn argmax(v: &[f32]) -> Option<usize> {
    v.iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, _)| i)
}

/// Decades of posterior shown in 3D (log scale: a softmax posterior is too peaked for a
/// linear colormap).
pub const LOG_DECADES: f32 = 3.0;

/// What the 3D view draws of a normalised value: log scale over [`LOG_DECADES`] decades in
/// [0, 1], the disagreement as it is (in [-1, 1]); [`value_rgb`] colours it.
pub fn shown_value(v: f32, kind: PosteriorKind) -> f32 {
    if kind == PosteriorKind::Disagreement {
        v
    } else {
        (1.0 + v.max(1e-12).log10() / LOG_DECADES).clamp(0.0, 1.0)
    }
}

/// The colour bar of the 3D posterior colours: ticks at the values they show (the posterior
/// over its maximum, log scale; the disagreement from geometry only to image only).
pub fn posterior_bar(kind: PosteriorKind) -> ColorBar {
    if kind == PosteriorKind::Disagreement {
        let ticks = [
            (-1.0, "-1: geometry only"),
            (0.0, "0"),
            (1.0, "+1: image only"),
        ]
        .into_iter()
        .map(|(v, l): (f32, &str)| ((v + 1.0) / 2.0, l.to_string()))
        .collect();
        return ColorBar::new(
            "target cloud: image minus geometric posterior, each over its maximum",
            ticks,
            |t| value_rgb(2.0 * t - 1.0, PosteriorKind::Disagreement),
        );
    }
    let decades = LOG_DECADES as i32;
    let ticks = (0..=decades)
        .map(|k| {
            let v = 10f32.powi(k - decades);
            let label = match k {
                0 => format!("<= {v}"),
                _ if k == decades => "1 (its maximum)".to_string(),
                _ => format!("{v}"),
            };
            (shown_value(v, kind), label)
        })
        .collect();
    ColorBar::new(
        format!(
            "target cloud: {} posterior over its maximum, log scale",
            kind.label()
        ),
        ticks,
        |t| value_rgb(t, PosteriorKind::Fused),
    )
}

/// The heat maps' colour bar: the posterior over its maximum, linear.
pub fn heat_map_bar() -> ColorBar {
    let ticks = [0.0f32, 0.25, 0.5, 0.75, 1.0]
        .into_iter()
        .map(|v| {
            (
                v,
                if v == 1.0 {
                    "1 (its maximum)".to_string()
                } else {
                    format!("{v}")
                },
            )
        })
        .collect();
    ColorBar::new(
        "heat maps: posterior over its maximum (linear; disagreement: magenta = image only, cyan = geometry only)",
        ticks,
        |t| value_rgb(t, PosteriorKind::Fused),
    )
}

/// Draws `bar` on its own line of `ui`.
fn bar_line(ui: &mut egui::Ui, bar: &ColorBar) {
    let (rect, _) = ui.allocate_exact_size(
        egui::vec2(ui.available_width().min(420.0), 62.0),
        egui::Sense::hover(),
    );
    color_bar(ui.painter(), rect.min, bar);
}

/// Target-cloud colours for the 3D posterior view: every target point within `SPLAT_M` of a
/// candidate takes the candidate's value (candidates are sparse keypoints among dense display
/// points), the rest dimmed. Log scale over `LOG_DECADES` except for the disagreement.
pub fn posterior_cloud_colors(
    model: &InspectorModel,
    p: &Posterior,
    kind: PosteriorKind,
) -> Vec<[u8; 4]> {
    const SPLAT_M: f32 = 0.04;
    let d = |c: u8| c / 4 + 30;
    let dim = [d(TARGET_RGB[0]), d(TARGET_RGB[1]), d(TARGET_RGB[2]), 255];
    let vals = normalised(p, kind);
    let (pos, val): (Vec<[f32; 3]>, Vec<f32>) = p
        .candidates
        .iter()
        .zip(&vals)
        .filter_map(|(ci, v)| model.target.get(*ci).map(|q| (*q, *v)))
        .unzip();
    if pos.is_empty() {
        return vec![dim; model.target.len()];
    }
    let shown = |v: f32| shown_value(v, kind);
    let index = KdIndex::new(&pos.iter().map(|p| view3d::point3(*p)).collect::<Vec<_>>());
    use rayon::prelude::*;
    model
        .target
        .par_iter()
        .map(|q| match index.nearest(&view3d::point3(*q)) {
            Some((i, d)) if d < SPLAT_M => {
                let c = value_rgb(shown(val[i]), kind);
                [c[0], c[1], c[2], 255]
            }
            _ => dim,
        })
        .collect()
}

fn heat_map(
    ui: &mut egui::Ui,
    shared: &Shared<'_>,
    views: &mut ViewsState,
    p: &Posterior,
    kind: PosteriorKind,
    size: egui::Vec2,
) {
    let model = shared.model;
    ui.vertical(|ui| {
        ui.strong(kind.label());
        let Some(tv) = model.target_views.get(p.target_view) else {
            ui.label("no target view");
            return;
        };
        let s = (size.x / tv.rgb.width as f32).min(size.y / tv.rgb.height as f32);
        let (rect, _) = ui.allocate_exact_size(
            egui::vec2(tv.rgb.width as f32 * s, tv.rgb.height as f32 * s),
            egui::Sense::hover(),
        );
        let tex = views.textures.get(
            ui.ctx(),
            shared.model_gen,
            &format!("tgt{}c", p.target_view),
            &tv.rgb,
        );
        image_in_rect(ui, &tex, rect);
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 0.0, egui::Color32::from_black_alpha(110));
        let vals = normalised(p, kind);
        // draw low values first so peaks stay on top
        let mut order: Vec<usize> = (0..vals.len()).collect();
        order.sort_by(|&a, &b| vals[a].abs().total_cmp(&vals[b].abs()));
        for i in order {
            let Some(px) = p.candidate_pixels.get(i).copied().flatten() else {
                continue;
            };
            let c = value_rgb(vals[i], kind);
            let a = (60.0 + 195.0 * vals[i].abs().sqrt()) as u8;
            painter.circle_filled(
                to_screen(rect, tv.rgb.width, tv.rgb.height, px),
                3.0,
                egui::Color32::from_rgba_unmultiplied(c[0], c[1], c[2], a),
            );
        }
        if kind != PosteriorKind::Disagreement {
            if let Some(px) =
                argmax(&vals).and_then(|i| p.candidate_pixels.get(i).copied().flatten())
            {
                let q = to_screen(rect, tv.rgb.width, tv.rgb.height, px);
                painter.rect_stroke(
                    egui::Rect::from_center_size(q, egui::vec2(10.0, 10.0)),
                    0.0,
                    egui::Stroke::new(2.0, egui::Color32::WHITE),
                    egui::StrokeKind::Middle,
                );
            }
        }
        if let Some(gt) = p.gt_target {
            if let Some(px) = p
                .candidates
                .iter()
                .position(|c| *c == gt)
                .and_then(|i| p.candidate_pixels.get(i).copied().flatten())
            {
                let q = to_screen(rect, tv.rgb.width, tv.rgb.height, px);
                let st = egui::Stroke::new(2.0, egui::Color32::from_rgb(60, 255, 90));
                painter.line_segment([q - egui::vec2(7.0, 0.0), q + egui::vec2(7.0, 0.0)], st);
                painter.line_segment([q - egui::vec2(0.0, 7.0), q + egui::vec2(0.0, 7.0)], st);
            }
        }
    });
}

impl Tab for PosteriorTab {
    fn panel(&self) -> Panel {
        Panel::Posterior
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        posterior_panel(ui, &mut cx.shared, cx.views, self);
    }
}

pub fn posterior_panel(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    views: &mut ViewsState,
    state: &mut PosteriorTab,
) {
    let model = shared.model;
    if model.posteriors.is_empty() {
        ui.label(if model.matches.is_empty() {
            "No posteriors: this run selected no correspondences (see the log)."
        } else {
            "No posteriors: they need the kept features of a run (FPFH); click a source point \
             in the Views or 3D tab to request one."
        });
        return;
    }
    let sel = shared.ui.selected_source_point;
    let opened = model.default_posterior.and_then(|s| model.posterior_for(s));
    let p = match sel.and_then(|s| model.posterior_for(s)) {
        Some(p) => p,
        None => {
            if let Some(s) = sel {
                ui.colored_label(
                    egui::Color32::from_rgb(230, 190, 60),
                    format!("posterior of source point {s} requested; showing the first available"),
                );
            }
            opened.unwrap_or(&model.posteriors[0])
        }
    };
    if !p.reason.is_empty() {
        ui.label(
            egui::RichText::new(format!("Source point #{}: {}", p.source_point, p.reason)).strong(),
        );
    }
    ui.horizontal_wrapped(|ui| {
        egui::ComboBox::from_label("Source point")
            .selected_text(format!("#{}", p.source_point))
            .show_ui(ui, |ui| {
                for q in &model.posteriors {
                    if ui
                        .selectable_label(
                            q.source_point == p.source_point,
                            format!("#{}", q.source_point),
                        )
                        .clicked()
                    {
                        shared.ui.selected_source_point = Some(q.source_point);
                    }
                }
            });
        let gt = p
            .gt_target
            .map(|g| format!("#{g}"))
            .unwrap_or_else(|| "unknown".into());
        ui.separator();
        ui.label(format!("GT target: {gt}"));
        for (name, row) in [
            ("image", &p.image),
            ("geometric", &p.geometric),
            ("fused", &p.fused),
        ] {
            if let Some(i) = argmax(row) {
                let hit = near_gt(model, p.source_point, p.candidates[i]);
                ui.separator();
                let r = model.gt_inlier_label();
                let (color, what) = match hit {
                    Some(true) => (
                        egui::Color32::from_rgb(90, 210, 110),
                        format!("GT inlier (within {r} of GT)"),
                    ),
                    Some(false) => (
                        egui::Color32::from_rgb(240, 80, 70),
                        format!("fails under GT (> {r} off)"),
                    ),
                    None => (ui.visuals().text_color(), "no GT".to_string()),
                };
                ui.colored_label(color, format!("{name} argmax #{} {what}", p.candidates[i]));
            }
        }
        ui.separator();
        match p.survived {
            Some(true) => ui.colored_label(
                egui::Color32::from_rgb(90, 210, 110),
                "match survived SC2-PCR",
            ),
            Some(false) => ui.colored_label(
                egui::Color32::from_rgb(240, 80, 70),
                "match rejected by SC2-PCR",
            ),
            None => ui.label("not estimated yet"),
        };
    });
    ui.label(egui::RichText::new("square: argmax · cross: ground truth   colours: turbo (low to high); disagreement: magenta = image only, cyan = geometry only").small());
    if model.target_views.is_empty() {
        if let Some(note) = &model.image_branch_note {
            ui.colored_label(egui::Color32::from_rgb(230, 190, 60), note);
        }
        if p.image.is_empty() {
            ui.label("No image posterior (image branch off): the target cloud shows the geometric posterior, which is also the fused one.");
        }
        ui.label(format!("3D: target points within 4 cm of a candidate keypoint, log scale over {LOG_DECADES} decades (turbo: low to high); white circle: the source point under the estimate"));
        posterior_3d(ui, shared, state, p, true);
        return;
    }
    bar_line(ui, &heat_map_bar());
    let w = (ui.available_width() - 30.0) / 4.0;
    let size = egui::vec2(w, w * 0.75);
    ui.horizontal(|ui| {
        // the source view with the selected point
        ui.vertical(|ui| {
            ui.strong(format!("source view {}", p.source_view));
            if let Some(sv) = model.source_views.get(p.source_view) {
                let s = (size.x / sv.rgb.width as f32).min(size.y / sv.rgb.height as f32);
                let (rect, _) = ui.allocate_exact_size(
                    egui::vec2(sv.rgb.width as f32 * s, sv.rgb.height as f32 * s),
                    egui::Sense::hover(),
                );
                let tex = views.textures.get(
                    ui.ctx(),
                    shared.model_gen,
                    &format!("src{}c", p.source_view),
                    &sv.rgb,
                );
                image_in_rect(ui, &tex, rect);
                if let Some(px) = p.source_pixel {
                    let q = to_screen(rect, sv.rgb.width, sv.rgb.height, px);
                    ui.painter().circle_stroke(
                        q,
                        7.0,
                        egui::Stroke::new(2.5, egui::Color32::WHITE),
                    );
                    ui.painter()
                        .circle_filled(q, 3.0, to_color32([255, 200, 20]));
                }
            }
        });
        heat_map(ui, shared, views, p, PosteriorKind::Image, size);
        heat_map(ui, shared, views, p, PosteriorKind::Geometric, size);
        heat_map(ui, shared, views, p, PosteriorKind::Fused, size);
    });
    ui.horizontal(|ui| {
        heat_map(ui, shared, views, p, PosteriorKind::Disagreement, size);
        ui.vertical(|ui| posterior_3d(ui, shared, state, p, false));
    });
    // below the row, so that the 3D view keeps the heat maps' height
    if let Some(kind) = state.kind3d {
        bar_line(ui, &posterior_bar(kind));
    }
}

/// The target cloud coloured by a posterior, with a chooser of which one (and its colour
/// bar above the view when `bar_above`; else the caller draws it).
fn posterior_3d(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    state: &mut PosteriorTab,
    p: &Posterior,
    bar_above: bool,
) {
    let model = shared.model;
    let kind = state.kind3d.get_or_insert(PosteriorKind::Fused);
    egui::ComboBox::from_label("target cloud coloured by")
        .selected_text(kind.label())
        .show_ui(ui, |ui| {
            for k in PosteriorKind::ALL {
                ui.selectable_value(kind, k, k.label());
            }
        });
    let kind = *kind;
    if bar_above {
        bar_line(ui, &posterior_bar(kind));
    }
    let key = (shared.model_gen, p.source_point, kind);
    if state.colors_key != Some(key) {
        state.colors = Some((
            view3d::next_id(),
            Arc::new(posterior_cloud_colors(model, p, kind)),
        ));
        state.colors_key = Some(key);
        let prefs = &mut state.view3d.prefs;
        prefs.show_lines = false;
        prefs.show_frusta = false;
        // the heat map is on the target: the source would hide it
        prefs.show_estimated = false;
        prefs.show_initial = false;
        prefs.show_ground_truth = false;
        prefs.point_size = prefs.point_size.max(3.0);
    }
    let over = state.colors.as_ref().map(|(id, c)| TargetOverride {
        id: *id,
        colors: c.clone(),
    });
    let prev = shared.ui.selected_source_point;
    shared.ui.selected_source_point = Some(p.source_point);
    view3d::scene_ui(ui, shared, &mut state.view3d, over);
    if shared.ui.selected_source_point == Some(p.source_point) {
        shared.ui.selected_source_point = prev.or(Some(p.source_point));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bar says what the target cloud shows: the best candidate's point has the colour
    /// of the top tick, a candidate under the bottom decade that of the bottom tick, and the
    /// ticks run up the bar.
    #[test]
    fn the_3d_colour_bar_matches_the_cloud_colours() {
        let model = InspectorModel::demo();
        let p = &model.posteriors[0];
        for kind in [
            PosteriorKind::Fused,
            PosteriorKind::Image,
            PosteriorKind::Geometric,
        ] {
            let bar = posterior_bar(kind);
            let pos: Vec<f32> = bar.ticks.iter().map(|t| t.0).collect();
            assert_eq!(pos.first(), Some(&0.0));
            assert_eq!(pos.last(), Some(&1.0));
            assert!(pos.windows(2).all(|w| w[0] < w[1]), "{pos:?}");
            let colors = posterior_cloud_colors(&model, p, kind);
            let vals = normalised(p, kind);
            let rgb = |c: [u8; 4]| [c[0], c[1], c[2]];
            let best = argmax(&vals).unwrap();
            assert_eq!(rgb(colors[p.candidates[best]]), (bar.map)(1.0), "{kind:?}");
            let low = vals.iter().position(|&v| v <= 1e-3 && v > 0.0);
            if let Some(i) = low {
                assert_eq!(rgb(colors[p.candidates[i]]), (bar.map)(0.0), "{kind:?}");
            }
        }
        let d = posterior_bar(PosteriorKind::Disagreement);
        assert_eq!((d.map)(1.0), value_rgb(1.0, PosteriorKind::Disagreement));
        assert_eq!((d.map)(0.0), value_rgb(-1.0, PosteriorKind::Disagreement));
        assert_eq!((d.map)(0.5), value_rgb(0.0, PosteriorKind::Disagreement));
    }
}
