//! Two settings compared over the open dataset, without bench JSONs: the user takes settings A
//! and settings B from the controls, and the worker registers the open dataset's pairs with
//! each (the "Run all" machinery, through the stage cache, with progress and Cancel). The two
//! runs come back as bench runs and the Compare tab shows them as it shows two files, with
//! what differs between A and B.

use eframe::egui;

use super::load::{settings_comparison, settings_run};
use super::{CompareAction, CompareTab, Side, WARN};
use crate::app::channel::{Command, LogLevel};
use crate::app::model::InspectorModel;
use crate::app::model::{CompareEvent, SettingsCompareRequest, SettingsRuns};
use crate::pipeline::params::RegisterParams;
use crate::report::compare::{self, json_diff};

/// The settings-comparison part of the Compare tab's state.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SettingsCompare {
    /// Settings A and B, taken from the controls.
    pub a: Option<RegisterParams>,
    pub b: Option<RegisterParams>,
    /// Only the first this many pairs of the open dataset (0: every pair).
    pub limit: usize,
    /// The comparison in progress: (settings, pair, done, total).
    pub progress: Option<(Side, String, usize, usize)>,
}

impl SettingsCompare {
    /// Takes `params` (the controls') as settings `side`.
    pub fn take(&mut self, side: Side, params: RegisterParams) {
        match side {
            Side::A => self.a = Some(params),
            Side::B => self.b = Some(params),
        }
    }

    fn get(&self, side: Side) -> Option<&RegisterParams> {
        match side {
            Side::A => self.a.as_ref(),
            Side::B => self.b.as_ref(),
        }
    }

    /// The worker's request over `model`'s pairs (the first `limit` of them when set); None
    /// until both settings are taken or while one runs.
    pub fn request(&self, model: &InspectorModel) -> Option<SettingsCompareRequest> {
        if self.progress.is_some() || model.pairs.is_empty() {
            return None;
        }
        let (a, b) = (self.a.clone()?, self.b.clone()?);
        let pairs = (self.limit > 0 && self.limit < model.pairs.len()).then(|| {
            model.pairs[..self.limit]
                .iter()
                .map(|p| p.id.clone())
                .collect()
        });
        Some(SettingsCompareRequest { a, b, pairs })
    }

    /// The settings that differ between A and B ("fusion.selection"), as the comparison
    /// names them.
    pub fn differences(&self) -> Vec<String> {
        let (Some(a), Some(b)) = (&self.a, &self.b) else {
            return Vec::new();
        };
        let value = |p: &RegisterParams| serde_json::to_value(p).unwrap_or_default();
        let mut lines = Vec::new();
        json_diff("", &value(a), &value(b), ("A", "B"), &mut lines);
        lines
    }
}

impl CompareTab {
    /// Takes a worker event of a settings comparison; returns lines for the log.
    pub fn on_event(&mut self, e: CompareEvent) -> Vec<(LogLevel, String)> {
        match e {
            CompareEvent::Progress {
                side,
                pair,
                done,
                total,
            } => {
                self.settings.progress = Some((side, pair, done, total));
                Vec::new()
            }
            CompareEvent::Finished(runs) => {
                self.settings.progress = None;
                let SettingsRuns {
                    a,
                    b,
                    request,
                    cancelled,
                } = *runs;
                let n = a.pairs.len().min(b.pairs.len());
                let l = settings_comparison(
                    settings_run("settings A", a, request.a),
                    settings_run("settings B", b, request.b),
                );
                let line = format!(
                    "compared settings A and B over {n} pairs of the open dataset{}: differ in {}",
                    if cancelled { " (cancelled)" } else { "" },
                    if l.comparison.differing_settings.is_empty() {
                        "nothing".to_string()
                    } else {
                        l.comparison.differing_settings.join(", ")
                    }
                );
                self.set_loaded(l);
                vec![(LogLevel::Info, line)]
            }
        }
    }
}

/// One settings line: "settings A: [take from the controls] FPFH ... | ...".
fn settings_line(ui: &mut egui::Ui, st: &SettingsCompare, side: Side) -> Option<CompareAction> {
    let mut action = None;
    ui.horizontal(|ui| {
        ui.strong(format!("settings {}", side.label()));
        if ui
            .add_enabled(
                st.progress.is_none(),
                egui::Button::new(format!("take {} from the controls", side.label())),
            )
            .on_hover_text("the settings the controls show now")
            .clicked()
        {
            action = Some(CompareAction::TakeSettings(side));
        }
        match st.get(side) {
            Some(p) => ui.label(compare::settings_summary(p)),
            None => ui.weak("not taken yet"),
        };
    });
    action
}

/// "Compare two settings over the open dataset": settings A and B, what differs, the pairs,
/// and Run (or the running comparison's progress and Cancel).
pub fn settings_section(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    st: &mut SettingsCompare,
) -> Option<CompareAction> {
    let mut action = None;
    for side in [Side::A, Side::B] {
        action = settings_line(ui, st, side).or(action);
    }
    ui.horizontal_wrapped(|ui| {
        if let (Some(_), Some(_)) = (&st.a, &st.b) {
            let d = st.differences();
            match d.len() {
                0 => ui.colored_label(WARN, "A and B are the same settings"),
                _ => ui
                    .label(format!("A and B differ in {}", d.join("; ")))
                    .on_hover_text(d.join("\n")),
            };
            ui.separator();
        }
        let n = model.pairs.len();
        ui.label("pairs:");
        ui.add_enabled(
            st.progress.is_none(),
            egui::DragValue::new(&mut st.limit).range(0..=n),
        )
        .on_hover_text("only the first N pairs of the open dataset (0: all of them)");
        let shown = if st.limit == 0 || st.limit >= n {
            n
        } else {
            st.limit
        };
        ui.weak(format!("{shown} of {n}"));
        match &st.progress {
            Some((side, pair, done, total)) => {
                let f = *done as f32 / (*total).max(1) as f32;
                ui.add(
                    egui::ProgressBar::new(f)
                        .desired_width(220.0)
                        .text(format!("{done} / {total} · {} · {pair}", side.label())),
                );
                if ui
                    .button("Cancel")
                    .on_hover_text("stop before the next registration; the pairs done under both settings are compared")
                    .clicked()
                {
                    action = Some(CompareAction::Send(Command::Cancel));
                }
            }
            None => {
                let req = st.request(model);
                let r = ui
                    .add_enabled(req.is_some(), egui::Button::new("Run A vs B"))
                    .on_hover_text(
                        "register these pairs with settings A and with settings B on the worker \
                         (stages in the cache load), then compare the two runs here",
                    )
                    .on_disabled_hover_text("take settings A and B from the controls first");
                if let (true, Some(req)) = (r.clicked(), req) {
                    st.progress = Some((Side::A, String::new(), 0, 2 * shown));
                    action = Some(CompareAction::Send(Command::CompareSettings(Box::new(req))));
                }
            }
        }
    });
    action
}
