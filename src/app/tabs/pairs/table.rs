//! The pair browser's table: a header that stays in view while the rows scroll under it
//! (and scrolls sideways with them), fixed column widths shared by the header and the rows,
//! one row per shown pair.

use eframe::egui;

use super::{PairColumn, PairSort};
use crate::app::channel::Command;
use crate::app::model::{InspectorModel, PairEntry, PairOutcome, PairStatus};

/// A clickable header cell; the sorted column shows its direction.
fn header(ui: &mut egui::Ui, column: PairColumn, sort: &mut PairSort) {
    let on = sort.column == column;
    let text = match (on, sort.descending) {
        (true, true) => format!("{} v", column.label()),
        (true, false) => format!("{} ^", column.label()),
        (false, _) => column.label().to_string(),
    };
    let r = ui
        .selectable_label(on, egui::RichText::new(text).strong())
        .on_hover_text("sort by this column (again: the other direction)");
    if r.clicked() {
        *sort = sort.clicked(column);
    }
}

fn outcome_color(o: PairOutcome) -> egui::Color32 {
    match o {
        PairOutcome::Success => egui::Color32::from_rgb(110, 200, 110),
        PairOutcome::Failure => egui::Color32::from_rgb(235, 160, 60),
        PairOutcome::Error => egui::Color32::from_rgb(240, 80, 70),
        PairOutcome::Running => egui::Color32::from_rgb(120, 170, 240),
        PairOutcome::Pending | PairOutcome::Done => egui::Color32::from_gray(170),
    }
}

fn status_cell(ui: &mut egui::Ui, p: &PairEntry, stale: bool) {
    let o = p.outcome();
    let settings = p
        .settings
        .as_ref()
        .map(|s| format!("settings {}: {}", s.id, s.summary))
        .unwrap_or_default();
    let r = if stale {
        ui.weak(format!("stale ({})", o.label()))
            .on_hover_text(format!(
                "computed with other settings than the current ones: {settings}"
            ))
    } else {
        ui.colored_label(outcome_color(o), o.label())
    };
    let r = match &p.status {
        PairStatus::Failed(m) => r.on_hover_text(m),
        _ => r,
    };
    if !stale && !settings.is_empty() {
        r.on_hover_text(settings);
    }
}

fn opt(v: Option<f64>, scale: f64, digits: usize) -> String {
    v.map(|x| format!("{:.*}", digits, x * scale))
        .unwrap_or_else(|| "-".into())
}

/// A cell's text (the pair column's is its id).
fn cell_text(p: &PairEntry, c: PairColumn) -> String {
    match c {
        PairColumn::Pair => p.id.clone(),
        PairColumn::Split => p.split.clone(),
        PairColumn::Status => p.outcome().label().to_string(),
        PairColumn::Rre => opt(p.rre_deg, 1.0, 2),
        PairColumn::Rte => opt(p.rte_m, 100.0, 1),
        PairColumn::InlierRatio => opt(p.inlier_ratio, 100.0, 1),
        PairColumn::Correspondences => p
            .correspondences
            .map(|n| n.to_string())
            .unwrap_or_else(|| "-".into()),
        PairColumn::Time => opt(p.time_ms, 1e-3, 2),
    }
}

/// The part of the ids every pair shares up to a '/' ("redkitchen-rgbd/"): the side list
/// leaves it out so long ids keep their distinguishing end in view.
pub fn common_id_prefix(model: &InspectorModel) -> String {
    let mut ids = model.pairs.iter().map(|p| p.id.as_str());
    let Some(first) = ids.next() else {
        return String::new();
    };
    let mut n = first.rfind('/').map_or(0, |i| i + 1);
    for id in ids {
        while n > 0 && !(id.len() >= n && id.as_bytes()[..n] == first.as_bytes()[..n]) {
            n = first[..n - 1].rfind('/').map_or(0, |i| i + 1);
        }
    }
    first[..n].to_string()
}

/// Column widths shared by the header and every row: the header (with its sort mark) or the
/// widest content, whichever is wider (measured on each column's longest few texts).
fn column_widths(
    ui: &egui::Ui,
    model: &InspectorModel,
    rows: &[usize],
    columns: &[PairColumn],
    id_prefix: &str,
) -> Vec<f32> {
    let font = egui::TextStyle::Body.resolve(ui.style());
    let strong = egui::TextStyle::Button.resolve(ui.style());
    let width = |t: &str, f: &egui::FontId| {
        ui.ctx().fonts_mut(|fonts| {
            fonts
                .layout_no_wrap(t.to_string(), f.clone(), egui::Color32::WHITE)
                .size()
                .x
        })
    };
    let pad = 2.0 * ui.spacing().button_padding.x + 2.0;
    columns
        .iter()
        .map(|&c| {
            let head = width(&format!("{} v", c.label()), &strong);
            // the longest few texts by characters, measured (bounded work on large datasets)
            let mut texts: Vec<String> = rows
                .iter()
                .map(|&i| match c {
                    PairColumn::Pair => model.pairs[i].id[id_prefix.len()..].to_string(),
                    _ => cell_text(&model.pairs[i], c),
                })
                .collect();
            texts.sort_by_key(|t| std::cmp::Reverse(t.chars().count()));
            texts.dedup();
            let body = texts
                .iter()
                .take(6)
                .map(|t| width(t, &font))
                .fold(0.0, f32::max);
            head.max(body) + pad
        })
        .collect()
}

/// `add` in a cell of width `w` and height `h`: text columns from the left, numbers from the
/// right.
fn fixed_cell<R>(
    ui: &mut egui::Ui,
    w: f32,
    h: f32,
    right: bool,
    add: impl FnOnce(&mut egui::Ui) -> R,
) -> R {
    let layout = if right {
        egui::Layout::right_to_left(egui::Align::Center)
    } else {
        egui::Layout::left_to_right(egui::Align::Center)
    };
    ui.allocate_ui_with_layout(egui::vec2(w, h), layout, |ui| {
        ui.set_width(w);
        ui.set_height(h);
        add(ui)
    })
    .inner
}

fn is_number(c: PairColumn) -> bool {
    !matches!(c, PairColumn::Pair | PairColumn::Split | PairColumn::Status)
}

/// What a list remembers between frames: the current pair it last scrolled to, and the part
/// of the rows it showed (only the rows in view are laid out, so a hidden current row is
/// scrolled to by its position).
#[derive(Debug, Default)]
pub struct ScrollMemo {
    pub current: Option<String>,
    /// The rows' area in view, in points from the first row's top (None before the first
    /// frame: the top of the list).
    pub viewport: Option<egui::Rangef>,
}

/// What a table shows: the rows (indices into the model's pairs, in order) and the columns
/// (the first is the pair id).
pub struct TableView<'a> {
    /// Distinguishes the side panel's table from the tab's (scroll state).
    pub id: &'a str,
    pub model: &'a InspectorModel,
    pub rows: &'a [usize],
    pub columns: &'a [PairColumn],
    /// Height of the rows' area; None: what the panel has left.
    pub max_height: Option<f32>,
    /// Header and rows scroll sideways together when wider than the panel (the tab); false:
    /// the table asks the panel for its width (the side panel grows to fit it).
    pub sideways: bool,
}

/// The table: the header stays in view above the rows, which scroll under it; the two
/// scroll sideways together when the columns are wider than the panel. Only the rows in view
/// are laid out. Clicking an id opens that pair; the current pair's row is scrolled into view
/// when it becomes current (only when hidden: a visible row stays where it is).
pub fn table(
    ui: &mut egui::Ui,
    v: TableView,
    sort: &mut PairSort,
    scrolled: &mut ScrollMemo,
    current_settings: Option<&str>,
    out: &mut Vec<Command>,
) {
    let id_prefix = if v.sideways {
        String::new()
    } else {
        common_id_prefix(v.model)
    };
    let mut widths = column_widths(ui, v.model, v.rows, v.columns, &id_prefix);
    let gap = ui.spacing().item_spacing.x;
    let mut total: f32 = widths.iter().sum::<f32>() + gap * widths.len().saturating_sub(1) as f32;
    if !v.sideways {
        // the side panel does not scroll sideways: the pair column gives up what does not
        // fit (its ids are elided, the full id is the tooltip), so the metrics stay in view
        let over = total - ui.available_width();
        if over > 0.0 {
            if let Some(w0) = widths.first_mut() {
                let shrunk = (*w0 - over).max(MIN_ID_WIDTH.min(*w0));
                total -= *w0 - shrunk;
                *w0 = shrunk;
            }
        }
    }
    let row_h = ui.spacing().interact_size.y;
    let mut body = |ui: &mut egui::Ui| {
        ui.horizontal(|ui| {
            for (&c, &w) in v.columns.iter().zip(&widths) {
                fixed_cell(ui, w, row_h, false, |ui| header(ui, c, sort));
            }
        });
        ui.separator();
        // what is left below the header, less the sideways scroll bar
        let bar = if v.sideways {
            ui.spacing().scroll.allocated_width()
        } else {
            0.0
        };
        let h = v
            .max_height
            .unwrap_or_else(|| ui.available_height() - bar)
            .max(row_h);
        // the current pair's row scrolled into view when it becomes current, only when it was
        // not wholly among the rows drawn last frame (a visible row stays where it is)
        let stride = row_h + ui.spacing().item_spacing.y;
        let mut offset = None;
        let at = v
            .model
            .current_pair
            .and_then(|c| v.rows.iter().position(|&i| i == c));
        if let Some(k) = at {
            let id = &v.model.pairs[v.rows[k]].id;
            if scrolled.current.as_deref() != Some(id.as_str()) {
                let seen = scrolled.viewport.unwrap_or(egui::Rangef::new(0.0, h));
                let top = k as f32 * stride;
                if top < seen.min || top + row_h > seen.max {
                    offset = Some((top - 0.5 * (h - row_h)).max(0.0));
                }
                scrolled.current = Some(id.clone());
            }
        }
        ui.allocate_ui_with_layout(
            egui::vec2(total, h),
            egui::Layout::top_down(egui::Align::Min),
            |ui| {
                ui.set_width(total);
                let mut area = egui::ScrollArea::vertical()
                    .id_salt((v.id, "rows"))
                    .max_height(h)
                    .auto_shrink([false, v.max_height.is_some()]);
                if let Some(o) = offset {
                    area = area.vertical_scroll_offset(o);
                }
                // only the rows in view are laid out: a frame costs the same at 10 or 10,000
                area.show_viewport(ui, |ui, viewport| {
                    scrolled.viewport = Some(viewport.y_range());
                    // as `ScrollArea::show_rows` lays them out
                    let n = v.rows.len();
                    let gap = ui.spacing().item_spacing.y;
                    ui.set_height((stride * n as f32 - gap).max(0.0));
                    let first = ((viewport.min.y / stride).floor().max(0.0) as usize).min(n);
                    let end = ((viewport.max.y / stride).ceil() as usize + 1).min(n);
                    let y0 = ui.max_rect().top() + first as f32 * stride;
                    let y1 = ui.max_rect().top() + end as f32 * stride;
                    let rect = egui::Rect::from_x_y_ranges(ui.max_rect().x_range(), y0..=y1);
                    ui.scope_builder(egui::UiBuilder::new().max_rect(rect), |ui| {
                        ui.skip_ahead_auto_ids(first);
                        let ctx = RowCtx {
                            current_settings,
                            id_prefix: &id_prefix,
                        };
                        rows(ui, &v, first..end.max(first), &widths, row_h, ctx, out)
                    });
                });
            },
        );
    };
    if v.sideways {
        egui::ScrollArea::horizontal()
            .id_salt((v.id, "sideways"))
            .auto_shrink([false, true])
            .show(ui, body);
    } else {
        body(ui);
    }
}

/// `text` as it fits `w` points: whole, else "…" and its end (ids that share a long start,
/// like PandaSet's "ego_000000-world_000040" and "…070", differ at the end).
fn keep_end(ui: &egui::Ui, text: &str, w: f32) -> String {
    let font = egui::TextStyle::Button.resolve(ui.style());
    let width = |t: &str| {
        ui.ctx().fonts_mut(|f| {
            f.layout_no_wrap(t.to_string(), font.clone(), egui::Color32::WHITE)
                .size()
                .x
        })
    };
    if width(text) <= w {
        return text.to_string();
    }
    let chars: Vec<char> = text.chars().collect();
    // the longest end that fits after the ellipsis (binary search on its length)
    let (mut lo, mut hi) = (0usize, chars.len());
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        let t: String = std::iter::once('…')
            .chain(chars[chars.len() - mid..].iter().copied())
            .collect();
        if width(&t) <= w {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    std::iter::once('…')
        .chain(chars[chars.len() - lo..].iter().copied())
        .collect()
}

/// The narrowest the pair column gets in a table that does not scroll sideways.
const MIN_ID_WIDTH: f32 = 80.0;

/// What the rows need besides the view: the settings in force and the ids' shared prefix
/// (left out).
struct RowCtx<'a> {
    current_settings: Option<&'a str>,
    id_prefix: &'a str,
}

/// The rows `range` of [`table`] (positions in the view's order), striped.
fn rows(
    ui: &mut egui::Ui,
    v: &TableView,
    range: std::ops::Range<usize>,
    widths: &[f32],
    row_h: f32,
    ctx: RowCtx<'_>,
    out: &mut Vec<Command>,
) {
    let RowCtx {
        current_settings,
        id_prefix,
    } = ctx;
    // ids that share a long start (PandaSet's "ego_000000-world_000040" and "...070") differ
    // at the end: keep it in view
    let shared_start = {
        let mut ids = v
            .rows
            .iter()
            .map(|&i| &v.model.pairs[i].id[id_prefix.len()..]);
        let first: Vec<char> = ids.next().map(|s| s.chars().collect()).unwrap_or_default();
        let common = ids.fold(first.len(), |n, id| {
            first
                .iter()
                .zip(id.chars())
                .take(n)
                .take_while(|(a, b)| *a == b)
                .count()
        });
        v.rows.len() > 1 && common >= 4
    };
    for (k, &i) in v
        .rows
        .iter()
        .enumerate()
        .skip(range.start)
        .take(range.len())
    {
        let p = &v.model.pairs[i];
        let stale = super::is_stale(p, current_settings);
        let shown_id = &p.id[id_prefix.len()..];
        let current = v.model.current_pair == Some(i);
        let stripe = ui.painter().add(egui::Shape::Noop);
        let row = ui.horizontal(|ui| {
            let id_w = widths.first().copied().unwrap_or(120.0);
            let r = fixed_cell(ui, id_w, row_h, false, |ui| {
                ui.style_mut().wrap_mode = Some(egui::TextWrapMode::Truncate);
                let pad = 2.0 * ui.spacing().button_padding.x + 2.0;
                let shown = if shared_start {
                    keep_end(ui, shown_id, id_w - pad)
                } else {
                    shown_id.to_string()
                };
                ui.selectable_label(current, shown).on_hover_text(&p.id)
            });
            for (&c, &w) in v.columns.iter().zip(widths).skip(1) {
                fixed_cell(ui, w, row_h, is_number(c), |ui| match c {
                    PairColumn::Status => status_cell(ui, p, stale),
                    _ if stale => {
                        ui.weak(cell_text(p, c));
                    }
                    _ => {
                        ui.label(cell_text(p, c));
                    }
                });
            }
            r
        });
        if k % 2 == 1 {
            let fill = ui.visuals().faint_bg_color;
            ui.painter().set(
                stripe,
                egui::epaint::RectShape::filled(row.response.rect, 0.0, fill),
            );
        }
        let r = row.inner;
        // the current row runs again when it is an error row (after a settings change)
        if r.clicked() && (!current || matches!(p.status, PairStatus::Failed(_))) {
            out.push(Command::SelectPair(p.id.clone()));
        }
    }
}
