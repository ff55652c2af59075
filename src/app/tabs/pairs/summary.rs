//! The pair browser's triage controls: the paper-style summary rows of the pairs run (the
//! numbers `cgenreg bench` prints, by the same function) and the next / previous failure.

use eframe::egui;

use super::{visible_pairs, PairSort, PairsTab};
use crate::app::channel::Command;
use crate::app::model::InspectorModel;
use crate::app::triage;

/// Opens the next (or previous) failure of the shown order after the current pair.
pub(super) fn go_to_failure(
    model: &InspectorModel,
    state: &mut PairsTab,
    sort: PairSort,
    forward: bool,
    out: &mut Vec<Command>,
) -> bool {
    let order = visible_pairs(&model.pairs, &state.filter, sort);
    let from = state
        .requested
        .as_ref()
        .and_then(|id| model.pairs.iter().position(|p| &p.id == id))
        .or(model.current_pair);
    let current = state.current_settings.as_deref();
    match triage::next_failure(&model.pairs, &order, from, forward, current) {
        Some(i) if Some(i) != from => {
            let id = model.pairs[i].id.clone();
            out.push(Command::SelectPair(id.clone()));
            state.requested = Some(id);
            true
        }
        _ => false,
    }
}

/// "previous / next failure" buttons (n / N).
pub fn failure_buttons(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut PairsTab,
    sort: PairSort,
    out: &mut Vec<Command>,
) {
    let running = state.progress.is_some();
    ui.horizontal(|ui| {
        let prev = ui
            .add_enabled(!running, egui::Button::new("< failure"))
            .on_hover_text("open the previous failure or error of the shown order (N)");
        let next = ui
            .add_enabled(!running, egui::Button::new("next failure >"))
            .on_hover_text("open the next failure or error of the shown order (n)");
        if prev.clicked() {
            go_to_failure(model, state, sort, false, out);
        }
        if next.clicked() {
            go_to_failure(model, state, sort, true, out);
        }
        ui.checkbox(&mut state.filter.failures_first, "failures first")
            .on_hover_text("failures and errors above the other rows, each in the sort's order");
    });
}

/// A summary number as `cgenreg bench` prints it ("–" when no registered pair gives one).
fn num(v: f64, scale: f64) -> String {
    if v.is_finite() {
        format!("{:.2}", scale * v)
    } else {
        "–".to_string()
    }
}

/// The paper-style rows of the pairs run with the settings in force: per benchmark and scene,
/// then each benchmark pooled, with the criterion they count by; clicking a row's benchmark or
/// scene shows only its pairs.
pub fn summary_table(ui: &mut egui::Ui, model: &InspectorModel, state: &mut PairsTab) {
    let (rows, n) = triage::summary_rows(&model.pairs, state.current_settings.as_deref());
    let Some(first) = rows.first() else {
        return;
    };
    let rmse = rows.iter().any(|r| r.rmse_recall.is_some());
    let also = rows.iter().find_map(|r| r.also.map(|(c, _)| c));
    ui.label(format!(
        "Summary of the {n} of {} pairs run with the current settings (as `cgenreg bench` \
         prints it): RR = registration recall at {}{}; RE / TE over the registered pairs",
        model.pairs.len(),
        first.criterion.label(),
        also.map_or(String::new(), |c| format!(
            ", RR {} at {}",
            c.short(),
            c.label()
        )),
    ));
    if rmse {
        ui.weak(
            "RR RMSE = the official 3DMatch recall: RMSE < 0.2 m over gt.info, on the pairs of \
             non-consecutive fragments",
        );
    }
    egui::Grid::new("pairs_field_summary")
        .striped(true)
        .min_col_width(40.0)
        .show(ui, |ui| {
            let mut head: Vec<String> = ["benchmark", "scene", "pairs", "RR %"]
                .map(String::from)
                .to_vec();
            if let Some(c) = also {
                head.push(format!("RR {} %", c.short()));
            }
            if rmse {
                head.push("RR RMSE % (pairs)".into());
            }
            head.extend(["RE mean °", "RE med °", "TE mean cm", "TE med cm"].map(String::from));
            for h in head {
                ui.strong(h);
            }
            ui.end_row();
            for r in &rows {
                let scene = r.scene.as_deref().unwrap_or("all");
                let picked = state.filter.split.as_deref() == Some(r.benchmark.as_str())
                    && state.filter.scene.as_deref() == r.scene.as_deref();
                if ui
                    .selectable_label(picked, &r.benchmark)
                    .on_hover_text("show only these pairs")
                    .clicked()
                {
                    state.filter.split = Some(r.benchmark.clone());
                    state.filter.scene = r.scene.clone();
                }
                if r.scene.is_some() {
                    ui.label(scene);
                } else {
                    ui.strong(scene);
                }
                ui.label(r.pairs.to_string());
                ui.label(format!("{:.1}", 100.0 * r.rr));
                if also.is_some() {
                    ui.label(
                        r.also
                            .map_or("-".into(), |(_, f)| format!("{:.1}", 100.0 * f)),
                    );
                }
                if rmse {
                    ui.label(r.rmse_recall.map_or("-".into(), |f| {
                        format!("{:.1} ({})", 100.0 * f, r.rmse_pairs)
                    }));
                }
                ui.label(num(r.re_mean_deg, 1.0));
                ui.label(num(r.re_median_deg, 1.0));
                ui.label(num(r.te_mean_m, 100.0));
                ui.label(num(r.te_median_m, 100.0));
                ui.end_row();
            }
        });
}
