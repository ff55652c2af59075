//! The Compare tab's header (the two runs and what differs between their settings) and the
//! selected pair's line with its "open with A / B" buttons.

use eframe::egui;

use super::{file_name, flip_color, fmt, CompareAction, CompareTab, LoadedComparison, Side, WARN};
use crate::app::model::InspectorModel;

/// The two runs, what differs between their parameters, and what keeps a run from opening.
pub(super) fn header(ui: &mut egui::Ui, l: &LoadedComparison) {
    let c = &l.comparison;
    egui::Grid::new("compare_header")
        .num_columns(3)
        .spacing([12.0, 2.0])
        .show(ui, |ui| {
            for side in [Side::A, Side::B] {
                let r = l.run(side);
                ui.strong(format!("run {}", side.label()));
                let name = ui.label(egui::RichText::new(&r.name).strong());
                match &r.path {
                    Some(p) => name.on_hover_text(p.display().to_string()),
                    None => name.on_hover_text("run here over the open dataset"),
                };
                ui.label(&r.summary);
                ui.end_row();
            }
        });
    match c.differing_settings.len() {
        0 => {
            ui.label("parameters: identical");
        }
        1 => {
            ui.label(format!(
                "the runs differ only in: {}",
                c.differing_settings[0]
            ));
        }
        n => {
            ui.colored_label(
                WARN,
                format!(
                    "the runs differ in {n} settings, not only the one compared: {}",
                    c.differing_settings.join(", ")
                ),
            );
        }
    }
    if !c.param_differences.is_empty() || !c.run_differences.is_empty() {
        egui::CollapsingHeader::new(format!(
            "what differs ({} values)",
            c.param_differences.len() + c.run_differences.len()
        ))
        .id_salt("compare_differences")
        .show(ui, |ui| {
            for d in &c.param_differences {
                ui.label(format!("params.{d}"));
            }
            for d in &c.run_differences {
                ui.label(format!("run: {d}"));
            }
        });
    }
    for side in [Side::A, Side::B] {
        let r = l.run(side);
        if let Err(e) = &r.params {
            ui.colored_label(
                WARN,
                format!(
                    "run {}: its settings cannot be rebuilt ({e}); \"open with {}\" is off",
                    side.label(),
                    side.label()
                ),
            );
        }
        for m in &r.missing {
            ui.colored_label(
                WARN,
                format!(
                    "run {}: {} is not on this machine; opening a pair with its settings fails \
                     where that file is needed",
                    side.label(),
                    m.display()
                ),
            );
        }
    }
}

/// The selected pair's line: both runs' numbers and the open buttons.
pub(super) fn selected_pair(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    st: &CompareTab,
) -> Option<CompareAction> {
    let l = st.loaded.as_ref()?;
    let mut action = None;
    ui.horizontal_wrapped(|ui| {
        let Some(p) = st
            .selected
            .as_ref()
            .and_then(|id| l.comparison.pairs.iter().find(|p| &p.id == id))
        else {
            ui.weak(
                "click a pair in the table or the scatter to open it with run A's or B's settings",
            );
            return;
        };
        ui.label(egui::RichText::new(&p.id).strong());
        ui.colored_label(flip_color(p.flip), p.flip.label());
        ui.label(format!(
            "RRE {} / {} deg, RTE {} / {} cm (A / B)",
            fmt(p.a.rre_deg, 1.0, 2),
            fmt(p.b.rre_deg, 1.0, 2),
            fmt(p.a.rte_m, 100.0, 1),
            fmt(p.b.rte_m, 100.0, 1)
        ));
        let in_dataset = model.pairs.iter().any(|e| e.id == p.id);
        for side in [Side::A, Side::B] {
            let r = l.run(side);
            let button = ui.add_enabled(
                r.params.is_ok() && in_dataset,
                egui::Button::new(format!("open with {}", side.label())),
            );
            let button = match &r.params {
                Ok(_) => button.on_hover_text(format!(
                    "register {} with run {}'s settings ({})",
                    p.id,
                    side.label(),
                    r.summary
                )),
                Err(e) => button.on_disabled_hover_text(e.clone()),
            };
            if button.clicked() {
                action = Some(CompareAction::Open(side, p.id.clone()));
            }
        }
        if !in_dataset {
            match l.a.manifest.as_ref().or(l.b.manifest.as_ref()) {
                Some(m) => {
                    ui.colored_label(WARN, "not in the open dataset:");
                    if ui
                        .button(format!("open {}", file_name(m)))
                        .on_hover_text(m.display().to_string())
                        .clicked()
                    {
                        action = Some(CompareAction::OpenManifest(m.clone()));
                    }
                }
                None => {
                    ui.colored_label(
                        WARN,
                        format!(
                            "not in the open dataset, and the runs' manifest ({}) is not found \
                             here: open it with Open...",
                            l.a.run.manifest.as_deref().unwrap_or("not recorded")
                        ),
                    );
                }
            }
        }
    });
    action
}
