//! Plots (egui_plot): RRE/RTE per pair, match precision-recall (Noisy-AND vs Noisy-OR,
//! figure 7), RRE/RTE against K (figure 6) and the prompt study (figure 4).

use eframe::egui;
use egui_plot::{Bar, BarChart, Legend, Line, Plot, PlotPoints, Points};

use super::model::InspectorModel;

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
pub fn per_pair_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) {
    let done: Vec<_> = model.pairs.iter().filter(|p| p.rre_deg.is_some()).collect();
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
        .filter(|p| matches!(p.status, super::model::PairStatus::Failed(_)))
        .count();
    plot(
        "per_pair",
        &if failed > 0 {
            format!("RRE / RTE per pair ({} done, {failed} failed)", done.len())
        } else {
            format!("RRE / RTE per pair ({} done)", done.len())
        },
        "pair",
        "RRE (°) · RTE (cm)",
        ui,
        h,
    )
    .include_y(0.0)
    .x_axis_formatter(move |mark, _range| {
        let i = mark.value.round();
        if (mark.value - i).abs() < 1e-6 && i >= 0.0 {
            names
                .get(i as usize)
                .map(|n| n.rsplit('/').next().unwrap_or(n).to_owned())
                .unwrap_or_default()
        } else {
            String::new()
        }
    })
    .show(ui, |p| {
        p.bar_chart(BarChart::new("RRE (°)", rre).color(RRE_COLOR));
        p.bar_chart(BarChart::new("RTE (cm)", rte).color(RTE_COLOR));
    });
}

pub fn pr_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) {
    let colors = [
        egui::Color32::from_rgb(60, 200, 90),
        egui::Color32::from_rgb(230, 80, 60),
    ];
    plot("pr", "Match precision–recall", "recall", "precision", ui, h)
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
        });
}

pub fn vs_k_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) {
    if model.plots.vs_k.is_empty() {
        no_data(
            ui,
            "RRE / RTE against K",
            "no runs over K for this dataset:\nthe K sweep needs the image branch",
            h,
        );
        return;
    }
    let rre: Vec<[f64; 2]> = model
        .plots
        .vs_k
        .iter()
        .map(|k| [k.k as f64, k.rre_deg])
        .collect();
    let rte: Vec<[f64; 2]> = model
        .plots
        .vs_k
        .iter()
        .map(|k| [k.k as f64, k.rte_m * 100.0])
        .collect();
    plot(
        "vs_k",
        "RRE / RTE against K",
        "K (views per scan)",
        "RRE (°) · RTE (cm)",
        ui,
        h,
    )
    .include_y(0.0)
    .show(ui, |p| {
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
    });
}

/// An empty plot area that says why it is empty.
fn no_data(ui: &mut egui::Ui, title: &str, why: &str, h: f32) {
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
}

pub fn prompt_plot(ui: &mut egui::Ui, model: &InspectorModel, h: f32) {
    let bars = &model.plots.prompt_study;
    if bars.is_empty() {
        no_data(
            ui,
            "Prompt study (cached generations)",
            "no cached generations for this dataset:\nthe prompt study needs the image branch",
            h,
        );
        return;
    }
    let rre: Vec<Bar> = bars
        .iter()
        .enumerate()
        .map(|(i, b)| {
            Bar::new(i as f64 - 0.18, b.rre_deg)
                .width(0.36)
                .name(format!("{} ({} pairs)", b.category, b.pairs))
        })
        .collect();
    let rte: Vec<Bar> = bars
        .iter()
        .enumerate()
        .map(|(i, b)| {
            Bar::new(i as f64 + 0.18, b.rte_m * 100.0)
                .width(0.36)
                .name(format!("{} ({} pairs)", b.category, b.pairs))
        })
        .collect();
    let names: Vec<String> = bars.iter().map(|b| b.category.clone()).collect();
    let top = bars
        .iter()
        .map(|b| b.rre_deg.max(b.rte_m * 100.0))
        .fold(0.0, f64::max);
    plot(
        "prompt",
        "Prompt study (cached generations)",
        "prompt category",
        "RRE (°) · RTE (cm)",
        ui,
        h,
    )
    .include_y(0.0)
    .include_y(top * 1.25)
    .x_axis_formatter(move |mark, _range| {
        let i = mark.value.round();
        if (mark.value - i).abs() < 1e-6 && i >= 0.0 {
            names.get(i as usize).cloned().unwrap_or_default()
        } else {
            String::new()
        }
    })
    .show(ui, |p| {
        p.bar_chart(BarChart::new("RRE (°)", rre).color(RRE_COLOR));
        p.bar_chart(BarChart::new("RTE (cm)", rte).color(RTE_COLOR));
    });
}

/// The four plots in a 2 x 2 grid.
pub fn plots_panel(ui: &mut egui::Ui, model: &InspectorModel) {
    let h = ((ui.available_height() - 60.0) / 2.0).max(120.0);
    let w = (ui.available_width() - 12.0) / 2.0;
    ui.columns(2, |cols| {
        let _ = w;
        per_pair_plot(&mut cols[0], model, h);
        vs_k_plot(&mut cols[0], model, h);
        pr_plot(&mut cols[1], model, h);
        prompt_plot(&mut cols[1], model, h);
    });
}
