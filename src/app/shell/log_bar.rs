//! The log bar at the bottom: the last line (with a spinner while a stage runs) and, when
//! opened, the whole log.

use super::*;

impl App {
    pub(super) fn log_bar(&mut self, ui: &mut egui::Ui) {
        // the status area: warnings and errors stay until dismissed (newest last)
        let mut dismiss = None;
        for (i, l) in self.status.iter().enumerate() {
            ui.horizontal(|ui| {
                if ui.small_button("×").on_hover_text("dismiss").clicked() {
                    dismiss = Some(i);
                }
                ui.colored_label(level_color(l.level), &l.text);
            });
        }
        if let Some(i) = dismiss {
            self.status.remove(i);
        }
        ui.horizontal(|ui| {
            let label = if self.show_log {
                "Hide log"
            } else {
                "Show log"
            };
            if ui.small_button(label).clicked() {
                self.show_log = !self.show_log;
            }
            if self
                .model
                .stages
                .iter()
                .any(|s| s.state == model::StageState::Running)
            {
                ui.spinner();
            }
            // the last message for a person (command echoes are in the log only)
            if let Some(l) = self.log.iter().rev().find(|l| !l.echo) {
                ui.colored_label(level_color(l.level), &l.text);
            } else {
                ui.weak("ready");
            }
        });
        if self.show_log {
            egui::ScrollArea::vertical()
                .id_salt("log")
                .max_height(260.0)
                .stick_to_bottom(true)
                .show(ui, |ui| {
                    for l in &self.log {
                        if l.echo {
                            ui.weak(&l.text);
                        } else {
                            ui.colored_label(level_color(l.level), &l.text);
                        }
                    }
                });
        }
    }
}

fn level_color(l: LogLevel) -> egui::Color32 {
    match l {
        LogLevel::Info => egui::Color32::from_gray(190),
        LogLevel::Warn => egui::Color32::from_rgb(230, 190, 60),
        LogLevel::Error => egui::Color32::from_rgb(240, 80, 70),
    }
}

/// A command for the log, cut at about 120 characters.
pub(super) fn short(c: &Command) -> String {
    let s = format!("{c:?}");
    if s.len() > 120 {
        format!(
            "{}…",
            &s[..s.char_indices().nth(117).map(|x| x.0).unwrap_or(s.len())]
        )
    } else {
        s
    }
}
