//! One source view and one target view side by side, every shown correspondence of that
//! view pair drawn as a line between them, with a K x K overview of where the matches fall.

mod image;
mod lines;

use eframe::egui;

use super::{Tab, TabContext};
use crate::app::colormap::turbo;
use crate::app::model::{InspectorModel, ViewImage};
use crate::app::state::{Panel, Shared};
use crate::app::view3d;
pub use image::{image_in_rect, to_screen, view_label, TextureCache, ViewsState, MAX_ZOOM};
use image::{zoom_and_pan, Layout, GAP, LABEL_H};
pub use lines::{best_pair, matches_in_pair, pair_counts};
use lines::{click_opens_posterior, highlights, hover_match, hover_tooltip, match_lines};

/// The Views tab (its state, the view pair and zoom, is shared with the Posterior tab:
/// [`TabContext::views`]).
#[derive(Default)]
pub struct ViewsTab;

impl Tab for ViewsTab {
    fn panel(&self) -> Panel {
        Panel::Views
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        let shared = &mut cx.shared;
        ui.checkbox(&mut shared.ui.show_3d_below_views, "3D view below");
        let h = ui.available_height();
        if shared.ui.show_3d_below_views {
            views_panel(ui, shared, cx.views, h * 0.62);
            view3d::scene_ui(ui, shared, cx.view3d, None);
        } else {
            views_panel(ui, shared, cx.views, h);
        }
    }
}

/// The K x K overview: one button per (source view, target view) with its match count;
/// clicking one shows that pair.
fn overview_grid(
    ui: &mut egui::Ui,
    counts: &[usize],
    ks: usize,
    kt: usize,
    chosen: (usize, usize),
) -> Option<(usize, usize)> {
    let max = counts.iter().copied().max().unwrap_or(0).max(1);
    let mut clicked = None;
    egui::Grid::new("view_pair_grid")
        .spacing(egui::vec2(2.0, 2.0))
        .show(ui, |ui| {
            ui.label(egui::RichText::new("src \\ tgt").small());
            for j in 0..kt {
                ui.label(egui::RichText::new(format!("t{j}")).small());
            }
            ui.end_row();
            for i in 0..ks {
                ui.label(egui::RichText::new(format!("s{i}")).small());
                for j in 0..kt {
                    let n = counts[i * kt + j];
                    let fill = if n == 0 {
                        egui::Color32::from_gray(40)
                    } else {
                        let c = turbo(0.15 + 0.7 * n as f32 / max as f32);
                        egui::Color32::from_rgb(c[0] / 2 + 20, c[1] / 2 + 20, c[2] / 2 + 20)
                    };
                    let sel = chosen == (i, j);
                    let b = egui::Button::new(
                        egui::RichText::new(n.to_string())
                            .small()
                            .color(egui::Color32::WHITE),
                    )
                    .fill(fill)
                    .stroke(if sel {
                        egui::Stroke::new(2.0, egui::Color32::WHITE)
                    } else {
                        egui::Stroke::NONE
                    })
                    .min_size(egui::vec2(30.0, 18.0));
                    if ui
                        .add(b)
                        .on_hover_text(format!(
                            "source view {i} / target view {j}: {n} of the shown matches"
                        ))
                        .clicked()
                    {
                        clicked = Some((i, j));
                    }
                }
                ui.end_row();
            }
        });
    clicked
}

/// The chosen source view next to the chosen target view, scaled to the panel, with a line
/// per shown match of that view pair; zoom (scroll, slider) and pan (drag) apply to both.
pub fn views_panel(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    state: &mut ViewsState,
    max_height: f32,
) {
    let model = shared.model;
    let (ks, kt) = (model.source_views.len(), model.target_views.len());
    if ks == 0 || kt == 0 {
        no_views_note(ui, model);
        return;
    }
    let top = ui.cursor().top();
    let shown = shared.shown_matches();
    let counts = pair_counts(model, &shown);
    let auto = best_pair(&counts, kt);
    if state.pair.is_some_and(|(i, j)| i >= ks || j >= kt) {
        state.pair = None;
    }
    let (si, ti) = state.pair.unwrap_or(auto);
    let pick = Pick { ks, kt, si, ti };
    let (sv, tv) = (&model.source_views[si], &model.target_views[ti]);
    let in_pair = matches_in_pair(sv, tv, &shown);
    header(ui, state, &counts, pick, (in_pair.len(), shown.len()));

    let layout = Layout::new(ui, top, max_height, sv, tv);
    zoom_and_pan(ui, &layout, state);
    let win = state.window();
    let painter = ui.painter_at(layout.area);
    for (v, r, side, k) in [(sv, layout.rs, "src", si), (tv, layout.rt, "tgt", ti)] {
        let img = if state.show_depth {
            v.depth.as_ref().unwrap_or(&v.rgb)
        } else {
            &v.rgb
        };
        let key = format!("{side}{k}{}", if state.show_depth { "d" } else { "c" });
        let tex = state.textures.get(ui.ctx(), shared.model_gen, &key, img);
        painter.image(tex.id(), r, win, egui::Color32::WHITE);
    }
    let segs = match_lines(&painter, shared, &layout, win, (sv, tv), &in_pair);
    hover_match(&layout.response, &segs, shared);
    highlights(&painter, shared, &segs, &layout, win, sv);
    hover_tooltip(&painter, shared, &layout.response);
    click_opens_posterior(&layout.response, &segs, shared);
    view_labels(ui, &layout, (si, sv), (ti, tv));
}

/// Why there are no views: the image branch is off (with its note) or the run is not done.
fn no_views_note(ui: &mut egui::Ui, model: &InspectorModel) {
    match &model.image_branch_note {
        Some(note) => {
            ui.colored_label(egui::Color32::from_rgb(230, 190, 60), "Image branch off");
            ui.label(note);
        }
        None => {
            ui.label("No views yet: the pair is still being registered.");
        }
    }
}

/// The view counts and the view pair shown.
#[derive(Clone, Copy)]
struct Pick {
    ks: usize,
    kt: usize,
    si: usize,
    ti: usize,
}

/// The overview grid, the view pickers, depth and zoom, and how many of the `shown` matches
/// fall in the pair (`counts`: (in the pair, shown)).
fn header(
    ui: &mut egui::Ui,
    state: &mut ViewsState,
    counts: &[usize],
    pick: Pick,
    (in_pair, shown): (usize, usize),
) {
    let Pick { ks, kt, si, ti } = pick;
    let elsewhere = shown - in_pair;
    ui.horizontal(|ui| {
        if ks * kt > 1 {
            if let Some(c) = overview_grid(ui, counts, ks, kt, (si, ti)) {
                state.pair = Some(c);
            }
            ui.separator();
        }
        ui.vertical(|ui| {
            view_pickers(ui, state, counts, pick);
            depth_and_zoom(ui, state);
            ui.label(format!(
                "{in_pair} of the {shown} shown matches fall in source view {si} / target view {ti}, each drawn as a line; the other {elsewhere} are not seen by both of these views.",
            ));
            ui.weak("scroll: zoom · drag: pan · double-click: reset · hover a match: highlight (here and in 3D) · click: open in Posterior");
        });
    });
}

/// Source and target view pickers (each entry with its match count), and "most matches".
fn view_pickers(ui: &mut egui::Ui, state: &mut ViewsState, counts: &[usize], pick: Pick) {
    let Pick { ks, kt, si, ti } = pick;
    ui.horizontal(|ui| {
        let mut s = si;
        let mut t = ti;
        egui::ComboBox::from_label("source view")
            .selected_text(format!("{si}"))
            .show_ui(ui, |ui| {
                for i in 0..ks {
                    ui.selectable_value(
                        &mut s,
                        i,
                        format!("{i} ({} in pair with target {ti})", counts[i * kt + ti]),
                    );
                }
            });
        egui::ComboBox::from_label("target view")
            .selected_text(format!("{ti}"))
            .show_ui(ui, |ui| {
                for j in 0..kt {
                    ui.selectable_value(
                        &mut t,
                        j,
                        format!("{j} ({} in pair with source {si})", counts[si * kt + j]),
                    );
                }
            });
        if (s, t) != (si, ti) {
            state.pair = Some((s, t));
        }
        if state.pair.is_some() && ui.small_button("most matches").clicked() {
            state.pair = None;
        }
    });
}

fn depth_and_zoom(ui: &mut egui::Ui, state: &mut ViewsState) {
    ui.horizontal(|ui| {
        ui.checkbox(&mut state.show_depth, "depth frames");
        ui.add(
            egui::Slider::new(&mut state.zoom, 1.0..=MAX_ZOOM)
                .logarithmic(true)
                .text("zoom"),
        );
        if ui.small_button("Reset zoom").clicked() {
            state.reset_zoom();
        }
    });
}

/// Each image's label (backend, prompt, cache entry) under it.
fn view_labels(
    ui: &mut egui::Ui,
    layout: &Layout,
    (si, sv): (usize, &ViewImage),
    (ti, tv): (usize, &ViewImage),
) {
    ui.horizontal(|ui| {
        ui.add_space((layout.x0 - layout.area.left()).max(0.0));
        ui.allocate_ui(egui::vec2(layout.rs.width(), LABEL_H), |ui| {
            ui.vertical(|ui| view_label(ui, "source", si, sv));
        });
        ui.add_space(GAP);
        ui.allocate_ui(egui::vec2(layout.rt.width(), LABEL_H), |ui| {
            ui.vertical(|ui| view_label(ui, "target", ti, tv));
        });
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_counts_match_a_direct_count_and_pick_the_fullest_pair() {
        let model = InspectorModel::demo();
        let shown: Vec<usize> = (0..model.matches.len()).collect();
        let counts = pair_counts(&model, &shown);
        let kt = model.target_views.len();
        for (i, sv) in model.source_views.iter().enumerate() {
            for (j, tv) in model.target_views.iter().enumerate() {
                let direct = (0..model.matches.len())
                    .filter(|&mi| sv.match_pixels[mi].is_some() && tv.match_pixels[mi].is_some())
                    .count();
                assert_eq!(counts[i * kt + j], direct);
                assert_eq!(matches_in_pair(sv, tv, &shown).len(), direct);
            }
        }
        let (i, j) = best_pair(&counts, kt);
        assert_eq!(counts[i * kt + j], *counts.iter().max().unwrap());
        assert!(counts[i * kt + j] > 0);
        assert_eq!(best_pair(&[0, 3, 3, 1], 2), (0, 1));
        assert_eq!(best_pair(&[], 0), (0, 0));
    }

    #[test]
    fn zoom_keeps_the_point_under_the_cursor_and_stays_inside_the_image() {
        let mut s = ViewsState::default();
        assert_eq!(
            s.window(),
            egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0))
        );
        let uv = egui::pos2(0.8, 0.3);
        let frac = (uv - s.window().min) / s.window().size();
        s.zoom_about(4.0, uv);
        let w = s.window();
        assert!((w.width() - 0.25).abs() < 1e-6);
        let back = w.min + frac * w.size();
        assert!((back - uv).length() < 1e-5, "{back:?}");
        // panning never leaves the image
        s.pan(egui::vec2(-10_000.0, 0.0), egui::vec2(100.0, 100.0));
        let w = s.window();
        assert!((w.max.x - 1.0).abs() < 1e-6 && w.min.x > 0.0, "{w:?}");
        s.zoom_about(0.01, uv);
        assert_eq!(s.zoom, 1.0);
        assert_eq!(s.window().min, egui::pos2(0.0, 0.0));
    }
}
