//! Hypothesis browser: the estimator's best hypotheses (SC2-PCR's seeds ranked by consensus
//! size, RANSAC's samples by its own order), each with its consensus, its RRE / RTE against
//! the ground truth, the winner marked. Selecting one shows its inlier set and its alignment
//! in the 3D view beside the list (and in the views: only its inliers are drawn).
//!
//! The worker computes the list on demand ([`Command::Hypotheses`], sent while this tab is
//! shown and the model has none), so registrations and re-fusions never pay for it.

use eframe::egui;

use super::{Tab, TabContext};
use crate::app::channel::Command;
use crate::app::model::InspectorModel;
use crate::app::state::{HypothesisView, Panel, Shared};
use crate::app::view3d::{self, View3dState};

/// The panel's own state: for which model the list was asked for.
#[derive(Clone, Debug, Default)]
pub struct HypothesesTab {
    asked_for: Option<u64>,
}

fn fmt_opt(v: Option<f64>, scale: f64, digits: usize) -> String {
    v.map(|x| format!("{:.*}", digits, x * scale))
        .unwrap_or_else(|| "-".into())
}

/// The list (left) and the 3D view (right).
impl Tab for HypothesesTab {
    fn panel(&self) -> Panel {
        Panel::Hypotheses
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        hypotheses_panel(ui, &mut cx.shared, self, cx.view3d);
    }
}

fn hypotheses_panel(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    state: &mut HypothesesTab,
    view: &mut View3dState,
) {
    let model = shared.model;
    if model.hypotheses.is_none()
        && !model.matches.is_empty()
        && state.asked_for != Some(shared.model_gen)
    {
        shared.commands.push(Command::Hypotheses);
        state.asked_for = Some(shared.model_gen);
    }
    if let Some(s) = &model.scale_note {
        // a scale search: the estimator's hypotheses below are those of the voxel kept
        ui.label(format!(
            "{s}; the estimator's hypotheses below are those of the voxel kept"
        ));
        ui.separator();
    }
    let list_w = 360.0_f32.min(ui.available_width() * 0.45);
    ui.horizontal_top(|ui| {
        ui.vertical(|ui| {
            ui.set_width(list_w);
            hypothesis_list(ui, shared);
        });
        ui.separator();
        ui.vertical(|ui| {
            if let Some(h) = &shared.ui.hypothesis {
                ui.label(format!(
                    "source under hypothesis #{}; lines: its consensus",
                    h.rank
                ));
            } else {
                ui.weak("select a hypothesis to see its alignment and consensus");
            }
            view3d::scene_ui(ui, shared, view, None);
        });
    });
}

/// The consensus set's shape: named when it cannot determine a pose (near-collinear, or
/// fewer than 3 points), by the library's test.
fn shape_cell(ui: &mut egui::Ui, model: &InspectorModel, matches: &[usize]) {
    use crate::pipeline::hypotheses::{spread_ratios, COLLINEAR_RATIO};
    let pts: Vec<nalgebra::Point3<f32>> = matches
        .iter()
        .filter_map(|&i| model.matches.get(i))
        .filter_map(|m| model.source.get(m.src))
        .map(|p| nalgebra::Point3::new(p[0], p[1], p[2]))
        .collect();
    let warn = egui::Color32::from_rgb(240, 150, 60);
    match spread_ratios(&pts) {
        None => {
            ui.colored_label(warn, "degenerate (< 3 points)");
        }
        Some((r2, r3)) if r2 < COLLINEAR_RATIO => {
            ui.colored_label(warn, "degenerate: near-collinear")
                .on_hover_text(format!(
                    "spread ratios {r2:.3}, {r3:.3}: a rotation about the line is free"
                ));
        }
        Some((r2, r3)) => {
            ui.weak("spread").on_hover_text(format!(
                "second / first principal spread {r2:.2}, third / first {r3:.2}"
            ));
        }
    }
}

/// The final estimate as its own row: the winner refined on its inliers (its consensus, the
/// estimator's kept matches, and its errors are the result's).
fn refined_row(ui: &mut egui::Ui, model: &InspectorModel) {
    let kept: Vec<usize> = (0..model.matches.len())
        .filter(|&i| model.matches[i].survived == Some(true))
        .collect();
    let row = model.current_pair.and_then(|i| model.pairs.get(i));
    ui.strong("refined");
    ui.label(kept.len().to_string());
    ui.label(fmt_opt(row.and_then(|r| r.rre_deg), 1.0, 2));
    ui.label(fmt_opt(row.and_then(|r| r.rte_m), 100.0, 1));
    ui.label("final estimate")
        .on_hover_text("the winner refined on its inliers: the pose the result reports");
    shape_cell(ui, model, &kept);
    ui.end_row();
}

fn hypothesis_list(ui: &mut egui::Ui, shared: &mut Shared<'_>) {
    let model = shared.model;
    ui.strong("Estimator hypotheses");
    let Some(list) = &model.hypotheses else {
        if model.matches.is_empty() {
            ui.weak("no registration yet");
        } else {
            ui.horizontal(|ui| {
                ui.spinner();
                ui.label("computing the hypotheses...");
            });
        }
        return;
    };
    if let Some(n) = &list.note {
        ui.label(n);
    }
    if list.rows.is_empty() {
        return;
    }
    ui.label(format!(
        "{}: best {} of {} hypotheses",
        list.estimator,
        list.rows.len(),
        list.total
    ));
    ui.small(&list.rule);
    let selected = shared.ui.hypothesis.as_ref().map(|h| h.rank);
    let mut clicked: Option<Option<usize>> = None;
    egui::ScrollArea::vertical()
        .id_salt("hypotheses")
        .show(ui, |ui| {
            egui::Grid::new("hypotheses_grid")
                .striped(true)
                .num_columns(6)
                .show(ui, |ui| {
                    ui.strong("rank");
                    ui.strong("consensus");
                    ui.strong("RRE deg");
                    ui.strong("RTE cm");
                    ui.strong("");
                    ui.strong("shape");
                    ui.end_row();
                    for (i, r) in list.rows.iter().enumerate() {
                        let on = selected == Some(r.rank);
                        if ui.selectable_label(on, format!("#{}", r.rank)).clicked() {
                            clicked = Some(if on { None } else { Some(i) });
                        }
                        ui.label(r.consensus.to_string());
                        ui.label(fmt_opt(r.rre_deg, 1.0, 2));
                        ui.label(fmt_opt(r.rte_m, 100.0, 1));
                        if r.winner {
                            ui.colored_label(egui::Color32::from_rgb(90, 210, 110), "winner");
                        } else {
                            ui.label("");
                        }
                        shape_cell(ui, model, &r.inliers);
                        ui.end_row();
                    }
                    refined_row(ui, model);
                });
        });
    if let Some(c) = clicked {
        shared.ui.hypothesis = c.map(|i| HypothesisView::of(&list.rows[i], model.matches.len()));
    }
}
