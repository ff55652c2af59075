//! One source view and one target view side by side, every shown correspondence of that
//! view pair drawn as a line between them, with a K x K overview of where the matches fall.

use std::collections::HashMap;

use eframe::egui;

use super::colormap::{to_color32, turbo, HIGHLIGHT_RGB};
use super::model::{InspectorModel, RgbImage, ViewImage};
use super::view3d::match_rgb;
use super::{Panel, Shared};

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

pub struct ViewsState {
    pub textures: TextureCache,
    /// Show the depth frames (as the WFM saw them) instead of the generated views.
    pub show_depth: bool,
    /// The (source view, target view) pair shown; None: the pair holding the most shown
    /// matches ([`best_pair`]).
    pub pair: Option<(usize, usize)>,
    /// Zoom (1: whole image) shared by both images.
    pub zoom: f32,
    /// Centre of the shown window, in normalised image coordinates (0..1), shared by both.
    pub center: [f32; 2],
}

impl Default for ViewsState {
    fn default() -> Self {
        Self {
            textures: TextureCache::default(),
            show_depth: false,
            pair: None,
            zoom: 1.0,
            center: [0.5, 0.5],
        }
    }
}

pub const MAX_ZOOM: f32 = 16.0;

impl ViewsState {
    pub fn reset_zoom(&mut self) {
        self.zoom = 1.0;
        self.center = [0.5, 0.5];
    }
    /// The shown window of each image in normalised coordinates.
    pub fn window(&self) -> egui::Rect {
        let z = self.zoom.clamp(1.0, MAX_ZOOM);
        let half = 0.5 / z;
        let c = [
            self.center[0].clamp(half, 1.0 - half),
            self.center[1].clamp(half, 1.0 - half),
        ];
        egui::Rect::from_min_max(
            egui::pos2(c[0] - half, c[1] - half),
            egui::pos2(c[0] + half, c[1] + half),
        )
    }
    /// Zooms by `factor` keeping the normalised image point `uv` where it is on screen.
    pub fn zoom_about(&mut self, factor: f32, uv: egui::Pos2) {
        let w = self.window();
        let frac = (uv - w.min) / w.size();
        self.zoom = (self.zoom * factor).clamp(1.0, MAX_ZOOM);
        let size = 1.0 / self.zoom;
        let min = uv - frac * size;
        self.center = [min.x + size / 2.0, min.y + size / 2.0];
        let c = self.window().center();
        self.center = [c.x, c.y];
    }
    /// Moves the window by a screen drag of `delta` over an image drawn `size` large.
    pub fn pan(&mut self, delta: egui::Vec2, size: egui::Vec2) {
        let w = self.window();
        let d = delta / size.max(egui::vec2(1.0, 1.0)) * w.size();
        self.center = [w.center().x - d.x, w.center().y - d.y];
        let c = self.window().center();
        self.center = [c.x, c.y];
    }
}

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

/// Pixel -> screen inside `rect`, which shows the normalised window `win` of the image.
fn to_screen_win(rect: egui::Rect, win: egui::Rect, img: &RgbImage, px: [f32; 2]) -> egui::Pos2 {
    let u = egui::pos2(
        (px[0] + 0.5) / img.width as f32,
        (px[1] + 0.5) / img.height as f32,
    );
    rect.min + ((u - win.min) / win.size()) * rect.size()
}

fn point_segment_distance(p: egui::Pos2, a: egui::Pos2, b: egui::Pos2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_sq().max(1e-6)).clamp(0.0, 1.0);
    (a + ab * t - p).length()
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

/// A drawn match on screen: (match index, source end, target end).
type Segment = (usize, egui::Pos2, egui::Pos2);

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

/// Where the two images go: both at one height, side by side with a small gap, as large as
/// the panel allows.
struct Layout {
    area: egui::Rect,
    response: egui::Response,
    /// The source and target image rectangles.
    rs: egui::Rect,
    rt: egui::Rect,
    x0: f32,
}

const GAP: f32 = 6.0;
const LABEL_H: f32 = 40.0;

impl Layout {
    fn new(ui: &mut egui::Ui, top: f32, max_height: f32, sv: &ViewImage, tv: &ViewImage) -> Layout {
        let used = ui.cursor().top() - top;
        let avail_w = ui.available_width();
        let avail_h = (max_height - used - LABEL_H).max(60.0);
        let (ws, hs) = (sv.rgb.width.max(1) as f32, sv.rgb.height.max(1) as f32);
        let (wt, ht) = (tv.rgb.width.max(1) as f32, tv.rgb.height.max(1) as f32);
        let (as_, at) = (ws / hs, wt / ht);
        let h = avail_h.min((avail_w - GAP) / (as_ + at)).max(20.0);
        let total = egui::vec2(h * (as_ + at) + GAP, h);
        let (area, response) =
            ui.allocate_exact_size(egui::vec2(avail_w, h), egui::Sense::click_and_drag());
        let x0 = area.left() + ((avail_w - total.x) / 2.0).max(0.0);
        let rs = egui::Rect::from_min_size(egui::pos2(x0, area.top()), egui::vec2(h * as_, h));
        let rt = egui::Rect::from_min_size(
            egui::pos2(rs.right() + GAP, area.top()),
            egui::vec2(h * at, h),
        );
        Layout {
            area,
            response,
            rs,
            rt,
            x0,
        }
    }
}

/// Zoom about the pointer, pan by dragging, double click resets.
fn zoom_and_pan(ui: &egui::Ui, layout: &Layout, state: &mut ViewsState) {
    let (response, rs, rt) = (&layout.response, layout.rs, layout.rt);
    if let Some(pos) = response.hover_pos() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if scroll != 0.0 {
            let r = if rt.contains(pos) { rt } else { rs };
            let w = state.window();
            let frac = ((pos - r.min) / r.size()).clamp(egui::Vec2::ZERO, egui::Vec2::splat(1.0));
            state.zoom_about((scroll * 0.0025).exp(), w.min + frac * w.size());
        }
    }
    if response.dragged() {
        state.pan(response.drag_delta(), rs.size());
    }
    if response.double_clicked() {
        state.reset_zoom();
    }
}

/// One line per match of the pair; with a zoom, those with an end outside the window are
/// left out (a line to an unseen point would cross the other image). Returns the drawn ones.
fn match_lines(
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
        painter.line_segment([pa, pb], egui::Stroke::new(1.2, c));
        painter.circle_filled(pa, 2.2, c);
        painter.circle_filled(pb, 2.2, c);
        segs.push((mi, pa, pb));
    }
    segs
}

/// The pointer near a line or an endpoint marks that match as hovered.
fn hover_match(response: &egui::Response, segs: &[Segment], shared: &mut Shared<'_>) {
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
fn highlights(
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
fn hover_tooltip(painter: &egui::Painter, shared: &Shared<'_>, response: &egui::Response) {
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
fn click_opens_posterior(response: &egui::Response, segs: &[Segment], shared: &mut Shared<'_>) {
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
