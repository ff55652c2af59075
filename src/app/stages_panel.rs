//! Pipeline stage states: cached, stale, running, failed (with the error) and time.

use eframe::egui;

use super::model::{InspectorModel, StageState};

pub fn state_text(s: &StageState) -> (String, egui::Color32) {
    match s {
        StageState::Cached => ("cached".into(), egui::Color32::from_rgb(120, 170, 255)),
        StageState::Stale => ("stale".into(), egui::Color32::from_rgb(230, 190, 60)),
        StageState::Running => ("running…".into(), egui::Color32::from_rgb(240, 240, 240)),
        StageState::Failed(m) => (format!("failed: {m}"), egui::Color32::from_rgb(240, 80, 70)),
        StageState::Done => ("done".into(), egui::Color32::from_rgb(90, 210, 110)),
    }
}

pub fn stages_panel(ui: &mut egui::Ui, model: &InspectorModel) {
    if model.stages.is_empty() {
        ui.label("No pipeline run yet.");
        return;
    }
    let total: f64 = model.stages.iter().filter_map(|s| s.time_ms).sum();
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
                ui.label(&s.name);
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
