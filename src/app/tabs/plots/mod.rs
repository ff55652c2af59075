//! Plots (egui_plot): RRE/RTE per pair, match precision-recall (Noisy-AND vs Noisy-OR,
//! figure 7), RRE/RTE against K (figure 6) and the prompt study (figure 4).

mod bar_axis;
use bar_axis::{bar_axis, every_bar};
use eframe::egui;
use egui_plot::{Bar, BarChart, Legend, Line, Plot, PlotPoints, Points};

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::{Tab, TabContext};
use crate::app::channel::{Command, StudyRequest};
use crate::app::model::InspectorModel;
use crate::app::state::Panel;

/// The plots panel's own inputs (the K list of the sweep, where plots are saved) and the
/// screen rectangles of its four plots in the last frame (to crop the PNGs from).
#[derive(Clone, Debug)]
pub struct PlotsTab {
    pub k_list: String,
    /// Folder of "Save plots": `<name>.png` and `<name>.csv` per plot.
    pub save_dir: String,
    /// A screenshot was asked for; its PNGs go to this folder when it arrives.
    pub pending_png: Option<PathBuf>,
    /// Where the screenshot callback puts the window's pixels.
    shot: Arc<Mutex<Option<Arc<egui::ColorImage>>>>,
    /// (plot file name, rectangle in points) as drawn in the last frame.
    pub rects: Vec<(&'static str, egui::Rect)>,
    /// What the last "Save plots" wrote (or why not).
    pub last_save: Option<String>,
    /// Save on the next frame as if the button were pressed (scripts and tests).
    pub save_now: bool,
}

impl Default for PlotsTab {
    fn default() -> Self {
        Self {
            k_list: "1,2,4,8".into(),
            save_dir: "cgenreg-plots".into(),
            pending_png: None,
            shot: Arc::default(),
            rects: Vec::new(),
            last_save: None,
            save_now: false,
        }
    }
}

/// The file stems of the four plots, in drawing order.
pub const PLOT_NAMES: [&str; 4] = [
    "rre_rte_per_pair",
    "rre_rte_vs_k",
    "match_pr",
    "prompt_study",
];

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x}")).unwrap_or_default()
}

/// The data of each plot as CSV text, `(file stem, text)` in [`PLOT_NAMES`] order (a header
/// row, then one row per bar / point; empty cells for unknown values).
pub fn plot_csvs(model: &InspectorModel) -> Vec<(&'static str, String)> {
    let mut per_pair = String::from("pair,status,rre_deg,rte_m,settings\n");
    for p in &model.pairs {
        let status = match &p.status {
            crate::app::model::PairStatus::Failed(_) => "failed",
            crate::app::model::PairStatus::Done => "done",
            crate::app::model::PairStatus::Running => "running",
            _ => "pending",
        };
        per_pair += &format!(
            "{},{status},{},{},{}\n",
            csv_field(&p.id),
            opt(p.rre_deg),
            opt(p.rte_m),
            p.settings.as_ref().map(|s| s.id.as_str()).unwrap_or("")
        );
    }
    let mut vs_k = String::from("k,rre_mean_deg,rte_mean_m,pairs,skipped,recall\n");
    for k in &model.plots.vs_k {
        vs_k += &format!(
            "{},{},{},{},{},{}\n",
            k.k,
            k.rre_deg,
            k.rte_m,
            k.pairs,
            k.skipped,
            opt(k.recall)
        );
    }
    let mut pr = String::from("curve,recall,precision\n");
    for c in &model.plots.pr_curves {
        for [r, p] in &c.points {
            pr += &format!("{},{r},{p}\n", csv_field(&c.name));
        }
    }
    let mut prompt = String::from("category,rre_mean_deg,rte_mean_m,pairs,skipped,recall\n");
    for b in &model.plots.prompt_study {
        prompt += &format!(
            "{},{},{},{},{},{}\n",
            csv_field(&b.category),
            b.rre_deg,
            b.rte_m,
            b.pairs,
            b.skipped,
            opt(b.recall)
        );
    }
    vec![
        (PLOT_NAMES[0], per_pair),
        (PLOT_NAMES[1], vs_k),
        (PLOT_NAMES[2], pr),
        (PLOT_NAMES[3], prompt),
    ]
}

/// Writes [`plot_csvs`] into `dir` (atomically, one file per plot); returns the files.
pub fn save_plot_csvs(dir: &Path, model: &InspectorModel) -> crate::Result<Vec<PathBuf>> {
    plot_csvs(model)
        .into_iter()
        .map(|(name, text)| {
            let p = dir.join(format!("{name}.csv"));
            crate::io::output::write_atomic(&p, text.as_bytes()).map(|_| p)
        })
        .collect()
}

/// Crops each plot's rectangle (points, scaled by `pixels_per_point`) out of a screenshot of
/// the window and writes it to `dir/<name>.png` (atomically); returns the files.
pub fn save_plot_pngs(
    dir: &Path,
    shot: &egui::ColorImage,
    pixels_per_point: f32,
    rects: &[(&'static str, egui::Rect)],
) -> crate::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for (name, rect) in rects {
        let part = shot.region(rect, Some(pixels_per_point));
        let [w, h] = part.size;
        if w == 0 || h == 0 {
            continue;
        }
        let rgba: Vec<u8> = part.pixels.iter().flat_map(|c| c.to_array()).collect();
        let img = image::RgbaImage::from_raw(w as u32, h as u32, rgba).ok_or_else(|| {
            crate::Error::Shape(format!("plot {name}: {w} x {h} pixels do not match"))
        })?;
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| crate::Error::Encode(format!("encoding {name}.png: {e}")))?;
        let p = dir.join(format!("{name}.png"));
        crate::io::output::write_atomic(&p, &png)?;
        out.push(p);
    }
    Ok(out)
}

/// "Save plots" with its folder: the CSVs at once, the PNGs from the next frame's screenshot.
fn save_bar(ui: &mut egui::Ui, model: &InspectorModel, state: &mut PlotsTab) {
    let mut log = None;
    let arrived = state.shot.lock().ok().and_then(|mut s| s.take());
    if let (Some(dir), Some(shot)) = (state.pending_png.clone(), arrived) {
        state.pending_png = None;
        let ppp = ui.ctx().pixels_per_point();
        log = Some(match save_plot_pngs(&dir, &shot, ppp, &state.rects) {
            Ok(files) => format!("saved {} plot PNGs in {}", files.len(), dir.display()),
            Err(e) => format!("plot PNGs not saved: {e}"),
        });
    }
    ui.horizontal(|ui| {
        let l = ui.label("Save plots to");
        ui.add(egui::TextEdit::singleline(&mut state.save_dir).desired_width(200.0))
            .labelled_by(l.id);
        let clicked = ui
            .add_enabled(
                state.pending_png.is_none() && !state.save_dir.trim().is_empty(),
                egui::Button::new("Save plots (PNG + CSV)"),
            )
            .on_hover_text("each plot as <name>.png (as drawn) and its data as <name>.csv")
            .clicked();
        if clicked || std::mem::take(&mut state.save_now) {
            let dir = PathBuf::from(state.save_dir.trim());
            log = Some(match save_plot_csvs(&dir, model) {
                Ok(files) => {
                    state.pending_png = Some(dir.clone());
                    let (slot, ctx) = (state.shot.clone(), ui.ctx().clone());
                    ui.ctx().request_screenshot(move |img| {
                        if let Ok(mut s) = slot.lock() {
                            *s = Some(img);
                        }
                        ctx.request_repaint();
                    });
                    format!("saved {} plot CSVs in {}", files.len(), dir.display())
                }
                Err(e) => format!("plot CSVs not saved: {e}"),
            });
        }
        if let Some(m) = &state.last_save {
            ui.weak(m);
        }
    });
    if log.is_some() {
        state.last_save = log;
    }
}

const K_EMPTY: &str = "no K sweep yet: press “Run K sweep” above\n(the open dataset's pairs, current settings, a WFM chosen)";
const PROMPT_EMPTY: &str = "no prompt study yet: press “Run prompt study” above\n(four prompt categories over the open dataset's pairs)";

const RRE_COLOR: egui::Color32 = egui::Color32::from_rgb(255, 170, 40);
const RTE_COLOR: egui::Color32 = egui::Color32::from_rgb(80, 160, 255);

fn plot(id: &str, title: &str, x: &str, y: &str, ui: &mut egui::Ui, h: f32) -> Plot<'static> {
    ui.strong(title);
    Plot::new(id.to_owned())
        .height(h)
        .legend(Legend::default())
        .x_axis_label(x.to_owned())
        .y_axis_label(y.to_owned())
        .allow_scroll(false)
}

/// RRE (degrees) and RTE (centimetres) share an axis so both read at a glance.
pub fn per_pair_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) -> egui::Rect {
    // one settings set at a time: the shown result's
    let current = model.settings.as_ref().map(|s| s.id.as_str());
    let stale = model
        .pairs
        .iter()
        .filter(|p| super::pairs::is_stale(p, current))
        .count();
    let done: Vec<_> = model
        .pairs
        .iter()
        .filter(|p| p.rre_deg.is_some() && !super::pairs::is_stale(p, current))
        .collect();
    let rre: Vec<Bar> = done
        .iter()
        .enumerate()
        .map(|(i, p)| {
            Bar::new(i as f64 - 0.18, p.rre_deg.unwrap_or(0.0))
                .width(0.36)
                .name(&p.id)
        })
        .collect();
    let rte: Vec<Bar> = done
        .iter()
        .enumerate()
        .map(|(i, p)| {
            Bar::new(i as f64 + 0.18, p.rte_m.unwrap_or(0.0) * 100.0)
                .width(0.36)
                .name(&p.id)
        })
        .collect();
    let names: Vec<String> = done.iter().map(|p| p.id.clone()).collect();
    let failed = model
        .pairs
        .iter()
        .filter(|p| {
            matches!(p.status, crate::app::model::PairStatus::Failed(_))
                && !super::pairs::is_stale(p, current)
        })
        .count();
    let mut title = if failed > 0 {
        format!("RRE / RTE per pair ({} done, {failed} failed)", done.len())
    } else {
        format!("RRE / RTE per pair ({} done)", done.len())
    };
    if stale > 0 {
        title.push_str(&format!(
            " · {stale} stale rows of other settings not shown"
        ));
    }
    let short: Vec<String> = names
        .iter()
        .map(|n| n.rsplit('/').next().unwrap_or(n).to_owned())
        .collect();
    plot("per_pair", &title, "pair", "RRE (°) · RTE (cm)", ui, h)
        .include_y(0.0)
        .x_grid_spacer(every_bar)
        .custom_x_axes(vec![bar_axis("pair", short)])
        .show(ui, |p| {
            p.bar_chart(BarChart::new("RRE (°)", rre).color(RRE_COLOR));
            p.bar_chart(BarChart::new("RTE (cm)", rte).color(RTE_COLOR));
        })
        .response
        .rect
}

pub fn pr_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) -> egui::Rect {
    let colors = [
        egui::Color32::from_rgb(60, 200, 90),
        egui::Color32::from_rgb(230, 80, 60),
    ];
    // Both fusion rules come from the worker's kept similarities (the paper's figure 7);
    // otherwise the one curve is the current fusion's matches (correct within the run's
    // inlier threshold).
    let title = if model.plots.pr_curves.len() == 2 {
        "Match precision–recall: Noisy-AND vs Noisy-OR (figure 7; correct within 5 cm under GT)"
            .to_string()
    } else {
        format!(
            "Match precision–recall (correct within {} under GT)",
            model.gt_inlier_label()
        )
    };
    plot("pr", &title, "recall", "precision", ui, h)
        .include_x(0.0)
        .include_x(1.0)
        .include_y(0.0)
        .include_y(1.0)
        .show(ui, |p| {
            for (i, c) in model.plots.pr_curves.iter().enumerate() {
                p.line(
                    Line::new(c.name.clone(), PlotPoints::from(c.points.clone()))
                        .color(colors[i % colors.len()])
                        .width(2.0),
                );
            }
        })
        .response
        .rect
}

pub fn vs_k_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) -> egui::Rect {
    let title = titled("RRE / RTE against K", &model.plots.vs_k_source);
    if model.plots.vs_k.is_empty() {
        return no_data(ui, &title, K_EMPTY, h);
    }
    let pts = &model.plots.vs_k;
    let rre: Vec<[f64; 2]> = pts.iter().map(|k| [k.k as f64, k.rre_deg]).collect();
    let rte: Vec<[f64; 2]> = pts.iter().map(|k| [k.k as f64, k.rte_m * 100.0]).collect();
    let counts = pts
        .iter()
        .map(|k| {
            format!(
                "K={}: {} pairs{}{}",
                k.k,
                k.pairs,
                if k.skipped > 0 {
                    format!(" ({} skipped)", k.skipped)
                } else {
                    String::new()
                },
                k.recall
                    .map(|r| format!(", RR {:.0} %", r * 100.0))
                    .unwrap_or_default()
            )
        })
        .collect::<Vec<_>>()
        .join(" · ");
    let pl = plot(
        "vs_k",
        &title,
        "K (views per scan)",
        "mean RRE (°) · RTE (cm)",
        ui,
        h,
    )
    .include_y(0.0)
    .include_x(0.0);
    ui.small(counts);
    pl.show(ui, |p| {
        p.line(
            Line::new("RRE (°)", PlotPoints::from(rre.clone()))
                .color(RRE_COLOR)
                .width(2.0),
        );
        p.points(
            Points::new("RRE (°)", PlotPoints::from(rre))
                .color(RRE_COLOR)
                .radius(3.0),
        );
        p.line(
            Line::new("RTE (cm)", PlotPoints::from(rte.clone()))
                .color(RTE_COLOR)
                .width(2.0),
        );
        p.points(
            Points::new("RTE (cm)", PlotPoints::from(rte))
                .color(RTE_COLOR)
                .radius(3.0),
        );
    })
    .response
    .rect
}

/// "title — source" when the source is known.
fn titled(title: &str, source: &str) -> String {
    if source.is_empty() {
        title.to_owned()
    } else {
        format!("{title} — {source}")
    }
}

/// An empty plot area that says why it is empty.
fn no_data(ui: &mut egui::Ui, title: &str, why: &str, h: f32) -> egui::Rect {
    ui.strong(title);
    let (rect, _) =
        ui.allocate_exact_size(egui::vec2(ui.available_width(), h), egui::Sense::hover());
    ui.painter().rect_stroke(
        rect,
        2.0,
        egui::Stroke::new(1.0, egui::Color32::from_gray(70)),
        egui::StrokeKind::Inside,
    );
    ui.painter().text(
        rect.center(),
        egui::Align2::CENTER_CENTER,
        why,
        egui::FontId::proportional(14.0),
        egui::Color32::from_gray(170),
    );
    rect
}

pub fn prompt_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) -> egui::Rect {
    let bars = &model.plots.prompt_study;
    let title = titled("Prompt study", &model.plots.prompt_source);
    if bars.is_empty() {
        return no_data(ui, &title, PROMPT_EMPTY, h);
    }
    let rre: Vec<Bar> = bars
        .iter()
        .enumerate()
        .map(|(i, b)| {
            Bar::new(i as f64 - 0.18, b.rre_deg)
                .width(0.36)
                .name(format!(
                    "{} ({} pairs, {} skipped)",
                    b.category, b.pairs, b.skipped
                ))
        })
        .collect();
    let rte: Vec<Bar> = bars
        .iter()
        .enumerate()
        .map(|(i, b)| {
            Bar::new(i as f64 + 0.18, b.rte_m * 100.0)
                .width(0.36)
                .name(format!(
                    "{} ({} pairs, {} skipped)",
                    b.category, b.pairs, b.skipped
                ))
        })
        .collect();
    let names: Vec<String> = bars.iter().map(|b| b.category.clone()).collect();
    let top = bars
        .iter()
        .map(|b| b.rre_deg.max(b.rte_m * 100.0))
        .fold(0.0, f64::max);
    let counts = bars
        .iter()
        .map(|b| {
            format!(
                "{}: {} pairs{}{}",
                b.category,
                b.pairs,
                if b.skipped > 0 {
                    format!(" ({} skipped)", b.skipped)
                } else {
                    String::new()
                },
                b.recall
                    .map(|r| format!(", RR {:.0} %", r * 100.0))
                    .unwrap_or_default()
            )
        })
        .collect::<Vec<_>>()
        .join(" · ");
    let pl = plot(
        "prompt",
        &title,
        "prompt category",
        "mean RRE (°) · RTE (cm)",
        ui,
        h,
    );
    ui.small(counts);
    pl.include_y(0.0)
        .include_y(top * 1.25)
        .x_grid_spacer(every_bar)
        .custom_x_axes(vec![bar_axis("prompt category", names)])
        .show(ui, |p| {
            p.bar_chart(BarChart::new("RRE (°)", rre).color(RRE_COLOR));
            p.bar_chart(BarChart::new("RTE (cm)", rte).color(RTE_COLOR));
        })
        .response
        .rect
}

/// The study buttons and progress, then the four plots in a 2 x 2 grid.
impl Tab for PlotsTab {
    fn panel(&self) -> Panel {
        Panel::Plots
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        plots_panel(ui, cx.shared.model, self, cx.shared.commands);
    }
}

fn plots_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut PlotsTab,
    commands: &mut Vec<Command>,
) {
    study_bar(ui, model, state, commands);
    save_bar(ui, model, state);
    if model.plots.figure7_pending && !commands.contains(&Command::Figure7) {
        // Repeated each frame until the worker answers; queued copies coalesce.
        commands.push(Command::Figure7);
    }
    let h = ((ui.available_height() - 60.0) / 2.0).max(120.0);
    let rects = ui.columns(2, |cols| {
        let a = per_pair_plot(&mut cols[0], model, h);
        let b = vs_k_plot(&mut cols[0], model, h);
        let c = pr_plot(&mut cols[1], model, h);
        let d = prompt_plot(&mut cols[1], model, h);
        [a, b, c, d]
    });
    state.rects = PLOT_NAMES.into_iter().zip(rects).collect();
}

/// "Run K sweep" (with its K list) and "Run prompt study": commands for the worker thread,
/// which runs the open dataset's pairs with the current settings; the UI keeps running.
fn study_bar(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut PlotsTab,
    commands: &mut Vec<Command>,
) {
    let running = model.plots.study_progress.clone();
    let ks = crate::pipeline::study::parse_ks(&state.k_list);
    ui.horizontal(|ui| {
        let l = ui.label("K values");
        ui.add(egui::TextEdit::singleline(&mut state.k_list).desired_width(90.0))
            .labelled_by(l.id);
        let busy = running.is_some();
        let k_btn = ui
            .add_enabled(!busy && ks.is_ok(), egui::Button::new("Run K sweep"))
            .on_hover_text("RRE/RTE against K (figure 6) over the open dataset's pairs");
        if k_btn.clicked() {
            if let Ok(ks) = &ks {
                commands.push(Command::RunStudy(StudyRequest::K(ks.clone())));
            }
        }
        if ui
            .add_enabled(!busy, egui::Button::new("Run prompt study"))
            .on_hover_text(
                "RRE/RTE per prompt category (figure 4): scene-specific, general, minimal, \
                 semantically wrong (+ the editor's scene as custom)",
            )
            .clicked()
        {
            commands.push(Command::RunStudy(StudyRequest::Prompt));
        }
        if let Err(e) = &ks {
            ui.colored_label(egui::Color32::from_rgb(230, 190, 60), e.to_string());
        }
        if let Some((what, done, total)) = &running {
            ui.add(
                egui::ProgressBar::new(*done as f32 / (*total).max(1) as f32)
                    .desired_width(220.0)
                    .text(format!("{what}: {done}/{total}")),
            );
            if ui
                .button("Cancel")
                .on_hover_text("stop before the next pair; the plot shows the pairs run so far")
                .clicked()
            {
                commands.push(Command::Cancel);
            }
        }
    });
}
