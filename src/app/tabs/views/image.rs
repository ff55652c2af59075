//! The two images: their textures, the shared zoom and pan, where they go in the panel, and
//! pixel to screen mappings.

use std::collections::HashMap;

use eframe::egui;

use crate::app::model::{RgbImage, ViewImage};

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
pub(super) fn to_screen_win(
    rect: egui::Rect,
    win: egui::Rect,
    img: &RgbImage,
    px: [f32; 2],
) -> egui::Pos2 {
    let u = egui::pos2(
        (px[0] + 0.5) / img.width as f32,
        (px[1] + 0.5) / img.height as f32,
    );
    rect.min + ((u - win.min) / win.size()) * rect.size()
}

/// Where the two images go: both at one height, side by side with a small gap, as large as
/// the panel allows.
pub(super) struct Layout {
    pub area: egui::Rect,
    pub response: egui::Response,
    /// The source and target image rectangles.
    pub rs: egui::Rect,
    pub rt: egui::Rect,
    pub x0: f32,
}

pub(super) const GAP: f32 = 6.0;
pub(super) const LABEL_H: f32 = 40.0;

impl Layout {
    pub fn new(
        ui: &mut egui::Ui,
        top: f32,
        max_height: f32,
        sv: &ViewImage,
        tv: &ViewImage,
    ) -> Layout {
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
pub(super) fn zoom_and_pan(ui: &egui::Ui, layout: &Layout, state: &mut ViewsState) {
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
