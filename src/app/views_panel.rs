//! The K source and target views side by side with correspondence lines between them.

use std::collections::HashMap;

use eframe::egui;

use super::colormap::{to_color32, HIGHLIGHT_RGB};
use super::model::{RgbImage, ViewImage};
use super::view3d::match_rgb;
use super::Shared;

/// GPU textures of view images, rebuilt when the model changes.
#[derive(Default)]
pub struct TextureCache {
    gen: u64,
    map: HashMap<String, egui::TextureHandle>,
}

impl TextureCache {
    pub fn get(
        &mut self,
        ctx: &egui::Context,
        gen: u64,
        key: &str,
        img: &RgbImage,
    ) -> egui::TextureHandle {
        if self.gen != gen {
            self.map.clear();
            self.gen = gen;
        }
        self.map
            .entry(key.to_owned())
            .or_insert_with(|| {
                let ci = egui::ColorImage::from_rgb(
                    [img.width as usize, img.height as usize],
                    &img.pixels,
                );
                ctx.load_texture(key, ci, egui::TextureOptions::LINEAR)
            })
            .clone()
    }
}

#[derive(Default)]
pub struct ViewsState {
    pub textures: TextureCache,
    /// Per row: show the depth frame instead of the RGB view.
    pub show_depth: Vec<bool>,
}

/// Draws one view image scaled into `rect`; returns the pixel -> screen mapping.
pub fn image_in_rect(ui: &egui::Ui, tex: &egui::TextureHandle, rect: egui::Rect) {
    ui.painter().image(
        tex.id(),
        rect,
        egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
        egui::Color32::WHITE,
    );
}

pub fn to_screen(rect: egui::Rect, img_w: u32, img_h: u32, px: [f32; 2]) -> egui::Pos2 {
    egui::pos2(
        rect.left() + (px[0] + 0.5) / img_w as f32 * rect.width(),
        rect.top() + (px[1] + 0.5) / img_h as f32 * rect.height(),
    )
}

/// Label under a view: backend, prompt and cache entry, never omitted.
pub fn view_label(ui: &mut egui::Ui, side: &str, k: usize, v: &ViewImage) {
    // the end of a prompt is its scene description (the start is the shared prefix)
    let n = v.label.prompt.chars().count();
    let prompt: String = if n > 60 {
        "…".to_string() + &v.label.prompt.chars().skip(n - 57).collect::<String>()
    } else {
        v.label.prompt.clone()
    };
    ui.label(
        egui::RichText::new(format!(
            "{side} view {k} · {} · {}",
            v.label.backend, v.label.cache_entry
        ))
        .small()
        .strong(),
    )
    .on_hover_text(&v.label.prompt);
    let prompt = if prompt.trim().is_empty() {
        "no prompt (this backend does not use one)".to_string()
    } else {
        format!("“{prompt}”")
    };
    ui.label(egui::RichText::new(prompt).small().italics())
        .on_hover_text(&v.label.prompt);
}

fn fit(avail: egui::Vec2, w: u32, h: u32) -> egui::Vec2 {
    let s = (avail.x / w as f32).min(avail.y / h as f32);
    egui::vec2(w as f32 * s, h as f32 * s)
}

fn point_segment_distance(p: egui::Pos2, a: egui::Pos2, b: egui::Pos2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_sq().max(1e-6)).clamp(0.0, 1.0);
    (a + ab * t - p).length()
}

/// One row per view index k: source view k on the left, target view k on the right.
pub fn views_panel(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    state: &mut ViewsState,
    max_height: f32,
) {
    let model = shared.model;
    let k = model.source_views.len().max(model.target_views.len());
    if k == 0 {
        match &model.image_branch_note {
            Some(note) => {
                ui.colored_label(egui::Color32::from_rgb(230, 190, 60), "Image branch off");
                ui.label(note);
            }
            None => {
                ui.label("No views yet: the pair is still being registered.");
            }
        }
        return;
    }
    state.show_depth.resize(k, false);
    let shown = shared.shown_matches();
    let highlight = shared.highlight();
    let row_h = ((max_height - 8.0) / k as f32 - 64.0).max(60.0);
    let gap = 36.0;
    egui::ScrollArea::vertical()
        .id_salt("views_scroll")
        .max_height(max_height)
        .show(ui, |ui| {
            for row in 0..k {
                let (sv, tv) = (model.source_views.get(row), model.target_views.get(row));
                ui.horizontal(|ui| {
                    ui.checkbox(
                        &mut state.show_depth[row],
                        format!("depth frames (row {row})"),
                    );
                });
                let avail_w = ui.available_width();
                let half = egui::vec2((avail_w - gap) / 2.0, row_h);
                let size_s = sv
                    .map(|v| fit(half, v.rgb.width, v.rgb.height))
                    .unwrap_or(half);
                let size_t = tv
                    .map(|v| fit(half, v.rgb.width, v.rgb.height))
                    .unwrap_or(half);
                let h = size_s.y.max(size_t.y);
                let (rect, response) =
                    ui.allocate_exact_size(egui::vec2(avail_w, h), egui::Sense::click());
                let rs = egui::Rect::from_min_size(rect.min, size_s);
                let rt = egui::Rect::from_min_size(
                    egui::pos2(rect.left() + half.x + gap, rect.top()),
                    size_t,
                );
                let depth = state.show_depth[row];
                for (v, r, side) in [(sv, rs, "src"), (tv, rt, "tgt")] {
                    let Some(v) = v else { continue };
                    let img = if depth {
                        v.depth.as_ref().unwrap_or(&v.rgb)
                    } else {
                        &v.rgb
                    };
                    let key = format!("{side}{row}{}", if depth { "d" } else { "c" });
                    let tex = state.textures.get(ui.ctx(), shared.model_gen, &key, img);
                    image_in_rect(ui, &tex, r);
                }
                // correspondence lines
                let painter = ui.painter_at(rect);
                let mut segs = Vec::new();
                if let (Some(sv), Some(tv)) = (sv, tv) {
                    for (rank, &mi) in shown.iter().enumerate() {
                        let a = sv.match_pixels.get(mi).copied().flatten();
                        let b = tv.match_pixels.get(mi).copied().flatten();
                        let c = to_color32(match_rgb(model, mi, rank, shared.ui.match_mode));
                        match (a, b) {
                            (Some(a), Some(b)) => {
                                let (pa, pb) = (
                                    to_screen(rs, sv.rgb.width, sv.rgb.height, a),
                                    to_screen(rt, tv.rgb.width, tv.rgb.height, b),
                                );
                                painter.line_segment([pa, pb], egui::Stroke::new(1.2, c));
                                painter.circle_filled(pa, 2.2, c);
                                painter.circle_filled(pb, 2.2, c);
                                segs.push((mi, pa, pb));
                            }
                            (Some(a), None) => {
                                painter.circle_stroke(
                                    to_screen(rs, sv.rgb.width, sv.rgb.height, a),
                                    2.5,
                                    egui::Stroke::new(1.0, c),
                                );
                            }
                            (None, Some(b)) => {
                                painter.circle_stroke(
                                    to_screen(rt, tv.rgb.width, tv.rgb.height, b),
                                    2.5,
                                    egui::Stroke::new(1.0, c),
                                );
                            }
                            (None, None) => {}
                        }
                    }
                    if let Some(mi) = highlight {
                        if let Some((_, pa, pb)) = segs.iter().find(|s| s.0 == mi) {
                            let hc = to_color32(HIGHLIGHT_RGB);
                            painter.line_segment([*pa, *pb], egui::Stroke::new(3.0, hc));
                            painter.circle_stroke(*pa, 6.0, egui::Stroke::new(2.0, hc));
                            painter.circle_stroke(*pb, 6.0, egui::Stroke::new(2.0, hc));
                        }
                    }
                    if let Some(sp) = shared.ui.selected_source_point {
                        if let Some(mi) = model.matches.iter().position(|m| m.src == sp) {
                            if let Some(a) = sv.match_pixels.get(mi).copied().flatten() {
                                painter.circle_stroke(
                                    to_screen(rs, sv.rgb.width, sv.rgb.height, a),
                                    8.0,
                                    egui::Stroke::new(2.0, egui::Color32::WHITE),
                                );
                            }
                        }
                    }
                }
                if let Some(pos) = response.hover_pos() {
                    let best = segs
                        .iter()
                        .map(|(mi, a, b)| (*mi, point_segment_distance(pos, *a, *b)))
                        .min_by(|a, b| a.1.total_cmp(&b.1));
                    if let Some((mi, d)) = best {
                        if d < 5.0 {
                            shared.ui.hovered_match = Some(mi);
                        }
                    }
                }
                if response.clicked() {
                    if let Some(mi) = shared.ui.hovered_match {
                        shared.select_match(mi);
                    } else if let (Some(pos), Some(sv)) = (response.interact_pointer_pos(), sv) {
                        // a click on the source image picks the nearest source endpoint
                        if rs.contains(pos) {
                            let best = sv
                                .match_pixels
                                .iter()
                                .enumerate()
                                .filter_map(|(mi, p)| {
                                    p.map(|p| {
                                        (
                                            mi,
                                            (to_screen(rs, sv.rgb.width, sv.rgb.height, p) - pos)
                                                .length(),
                                        )
                                    })
                                })
                                .min_by(|a, b| a.1.total_cmp(&b.1));
                            if let Some((mi, d)) = best {
                                if d < 15.0 {
                                    shared.select_source_point(model.matches[mi].src);
                                }
                            }
                        }
                    }
                }
                ui.horizontal(|ui| {
                    ui.allocate_ui(egui::vec2(half.x, 44.0), |ui| {
                        ui.vertical(|ui| {
                            if let Some(v) = sv {
                                view_label(ui, "source", row, v);
                            }
                        });
                    });
                    ui.add_space(gap);
                    ui.allocate_ui(egui::vec2(half.x, 44.0), |ui| {
                        ui.vertical(|ui| {
                            if let Some(v) = tv {
                                view_label(ui, "target", row, v);
                            }
                        });
                    });
                });
            }
        });
}
