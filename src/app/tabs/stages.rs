//! Pipeline stage states: cached, stale, running, failed (with the error) and time.

use eframe::egui;

use super::{Tab, TabContext};
use crate::app::channel::Command;
use crate::app::model::{InspectorModel, StageInfo, StageRole, StageState};
use crate::app::state::Panel;

/// The stage panel's total: the timed top-level rows (stages and containers), not the parts a
/// container already includes. With no timed container (e.g. a run still in progress, or rows
/// from a bench file) every timed row counts.
pub fn stage_total_ms(stages: &[StageInfo]) -> f64 {
    let has_container = stages
        .iter()
        .any(|s| s.role == StageRole::Container && s.time_ms.is_some());
    stages
        .iter()
        .filter(|s| !has_container || s.role != StageRole::Part)
        .filter_map(|s| s.time_ms)
        .sum()
}

/// The stage panel's own input: where "Export correspondences..." writes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StagesTab {
    /// Empty: `correspondences-<pair>.npz` in the working directory.
    pub export_path: String,
}

/// The default export file of a pair: `correspondences-<pair id, '/' as '_'>.npz`.
pub fn default_export_name(pair_id: &str) -> String {
    let safe: String = pair_id
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("correspondences-{safe}.npz")
}

/// "Export correspondences..." with its file: the worker writes the current pair's selected
/// correspondences there (the library's `pipeline::export`, as `register --export-corr`).
pub fn export_bar(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut StagesTab,
    commands: &mut Vec<Command>,
) {
    let pair = model
        .current_pair
        .and_then(|i| model.pairs.get(i))
        .map(|p| p.id.clone());
    ui.horizontal(|ui| {
        let clicked = ui
            .add_enabled(
                pair.is_some() && !model.matches.is_empty(),
                egui::Button::new("Export correspondences..."),
            )
            .on_hover_text(
                "write the selected correspondences (indices, xyz, fused / image / geometric \
                 posterior, proposing branch, inlier under the estimate and under GT) to this \
                 .npz",
            )
            .clicked();
        let hint = pair.as_deref().map(default_export_name).unwrap_or_default();
        ui.add(
            egui::TextEdit::singleline(&mut state.export_path)
                .hint_text(hint.clone())
                .desired_width(320.0),
        );
        if clicked {
            let path = if state.export_path.trim().is_empty() {
                hint
            } else {
                state.export_path.trim().to_string()
            };
            commands.push(Command::ExportCorrespondences(path.into()));
        }
    });
    ui.separator();
}

pub fn state_text(s: &StageState) -> (String, egui::Color32) {
    match s {
        StageState::Cached => ("cached".into(), egui::Color32::from_rgb(120, 170, 255)),
        StageState::Stale => ("stale".into(), egui::Color32::from_rgb(230, 190, 60)),
        StageState::Running => ("running…".into(), egui::Color32::from_rgb(240, 240, 240)),
        StageState::Failed(m) => (format!("failed: {m}"), egui::Color32::from_rgb(240, 80, 70)),
        StageState::Done => ("done".into(), egui::Color32::from_rgb(90, 210, 110)),
    }
}

impl Tab for StagesTab {
    fn panel(&self) -> Panel {
        Panel::Stages
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        stages_panel(ui, cx.shared.model, self, cx.shared.commands);
    }
}

fn stages_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut StagesTab,
    commands: &mut Vec<Command>,
) {
    export_bar(ui, model, state, commands);
    if model.stages.is_empty() {
        ui.label("No pipeline run yet.");
        return;
    }
    // the parts a container row includes are not added a second time
    let total = stage_total_ms(&model.stages);
    egui::Grid::new("stages")
        .striped(true)
        .num_columns(4)
        .spacing([24.0, 6.0])
        .show(ui, |ui| {
            ui.strong("stage");
            ui.strong("state");
            ui.strong("time");
            ui.strong("");
            ui.end_row();
            for s in &model.stages {
                match s.role {
                    StageRole::Part => ui.label(format!("    {}", s.name)),
                    StageRole::Container => ui
                        .strong(&s.name)
                        .on_hover_text("its time includes the indented stages below"),
                    StageRole::Stage => ui.label(&s.name),
                };
                let (t, c) = state_text(&s.state);
                if matches!(s.state, StageState::Running) {
                    ui.horizontal(|ui| {
                        ui.spinner();
                        ui.colored_label(c, t);
                    });
                } else {
                    ui.colored_label(c, t);
                }
                ui.label(
                    s.time_ms
                        .map(|t| format!("{t:.1} ms"))
                        .unwrap_or_else(|| "–".into()),
                );
                // a bar proportional to the stage's share of the run
                let frac = s
                    .time_ms
                    .map(|t| (t / total.max(1e-9)) as f32)
                    .unwrap_or(0.0);
                let (r, _) = ui.allocate_exact_size(egui::vec2(160.0, 10.0), egui::Sense::hover());
                ui.painter()
                    .rect_filled(r, 2.0, egui::Color32::from_gray(50));
                let mut f = r;
                f.set_width(r.width() * frac);
                ui.painter().rect_filled(f, 2.0, c);
                ui.end_row();
            }
            ui.strong("total");
            ui.label("");
            ui.strong(format!("{total:.1} ms"));
            ui.end_row();
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(name: &str, ms: Option<f64>, role: StageRole) -> StageInfo {
        StageInfo {
            name: name.into(),
            stage: None,
            state: StageState::Done,
            time_ms: ms,
            role,
        }
    }

    #[test]
    fn total_adds_containers_not_their_parts() {
        // a run: "load + register" 12.6 s includes its stages (7.5 s of them timed)
        let run = [
            row("load + register", Some(12_600.0), StageRole::Container),
            row("FPFH", Some(4_000.0), StageRole::Part),
            row("fusion", Some(3_500.0), StageRole::Part),
        ];
        assert_eq!(stage_total_ms(&run), 12_600.0);
        // a re-fuse: the key comparison is timed on its own, next to the re-fuse row
        let refuse = [
            row("re-fuse from memory", Some(30.0), StageRole::Container),
            row(
                "settings change: no stage key changed",
                Some(2.0),
                StageRole::Stage,
            ),
            row("FPFH", Some(0.0), StageRole::Part),
            row("fusion", Some(20.0), StageRole::Part),
        ];
        assert_eq!(stage_total_ms(&refuse), 32.0);
        // still running (the container has no time yet), or no container at all: every row
        let running = [
            row("load + register", None, StageRole::Container),
            row("FPFH", Some(4.0), StageRole::Part),
            row("fusion", Some(3.0), StageRole::Part),
        ];
        assert_eq!(stage_total_ms(&running), 7.0);
        assert_eq!(stage_total_ms(&[]), 0.0);
    }
}
