//! The left side panel: opening data, the pair browser, how correspondences are drawn, the
//! missing-generation prompt and the pipeline controls.

use super::*;

impl App {
    /// Everything in the left panel; commands and an open request go back to [`App::show`].
    pub(super) fn side_panel(
        &mut self,
        ui: &mut egui::Ui,
        commands: &mut Vec<Command>,
        open_request: &mut Option<OpenKind>,
    ) {
        ui.horizontal(|ui| {
            ui.heading("C-GenReg inspector");
        });
        self.open_menu(ui, open_request);
        self.reopen_last(ui, commands);
        ui.separator();
        ui.strong("Pairs");
        pairs_panel::pairs_panel(
            ui,
            &self.model,
            &mut self.pairs,
            &mut self.ui_state.pair_sort,
            commands,
        );
        ui.separator();
        ui.strong("Correspondences");
        self.match_display_controls(ui);
        self.correspondence_summary(ui);
        ui.separator();
        self.generation_missing_prompt(ui, commands);
        let scene = self.scene_specific_prompt();
        controls::controls_ui(ui, &mut self.params, &mut self.image_off, &scene, commands);
    }

    /// "Open..." with one entry per kind of data, and the built-in browser switch.
    fn open_menu(&mut self, ui: &mut egui::Ui, open_request: &mut Option<OpenKind>) {
        ui.menu_button("Open…", |ui| {
            for k in [
                OpenKind::Manifest,
                OpenKind::ThreeDMatchFolder,
                OpenKind::RgbdSequence,
                OpenKind::TwoClouds,
                OpenKind::CosmosOutput,
                OpenKind::Comparison,
            ] {
                if ui.button(k.label()).clicked() {
                    *open_request = Some(k);
                    ui.close();
                }
            }
            ui.separator();
            ui.checkbox(&mut self.builtin_browser, "built-in file browser")
                .on_hover_text(
                    "instead of the desktop's dialog (chosen by itself where \
                     there is none: no xdg portal or zenity)",
                );
        });
    }

    /// "Reopen last", when something was opened before.
    fn reopen_last(&self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        if let Some((k, paths)) = self.last_opened.clone() {
            if ui
                .small_button("Reopen last")
                .on_hover_text(format!("{paths:?}"))
                .clicked()
            {
                commands.push(Command::Open { kind: k, paths });
            }
        }
    }

    /// Match colours, how many matches are drawn, and whether only estimator inliers are.
    fn match_display_controls(&mut self, ui: &mut egui::Ui) {
        egui::ComboBox::from_label("Match colours")
            .selected_text(self.ui_state.match_mode.label())
            .show_ui(ui, |ui| {
                for m in MatchColorMode::ALL {
                    ui.selectable_value(&mut self.ui_state.match_mode, m, m.label());
                }
            });
        // The range always holds the current value: a slider clamps to its range, and the
        // empty model at start-up would pin the count to 1.
        let n = self
            .model
            .matches
            .len()
            .max(self.ui_state.match_count)
            .max(1);
        ui.add(egui::Slider::new(&mut self.ui_state.match_count, 0..=n).text("matches shown"));
        let kept = self.kept_matches();
        ui.checkbox(
            &mut self.ui_state.only_survivors,
            format!(
                "only estimator inliers ({kept} of {})",
                self.model.matches.len()
            ),
        );
    }

    /// Matches the estimator kept (SC2-PCR inliers).
    fn kept_matches(&self) -> usize {
        self.model
            .matches
            .iter()
            .filter(|m| m.survived == Some(true))
            .count()
    }

    /// Ground-truth inlier counts, and the selected match.
    fn correspondence_summary(&self, ui: &mut egui::Ui) {
        let kept = self.kept_matches();
        let gt_known: Vec<bool> = self
            .model
            .matches
            .iter()
            .filter_map(|m| m.inlier_gt)
            .collect();
        if !gt_known.is_empty() {
            let inl = gt_known.iter().filter(|x| **x).count();
            let kept_inl = self
                .model
                .matches
                .iter()
                .filter(|m| m.survived == Some(true) && m.inlier_gt == Some(true))
                .count();
            ui.label(format!(
                "GT inliers (10 cm): {inl} of {} matches ({:.1} %); {kept_inl} of {kept} kept",
                gt_known.len(),
                100.0 * inl as f64 / gt_known.len() as f64
            ));
        }
        if let Some(mi) = self.ui_state.selected_match {
            if let Some(m) = self.model.matches.get(mi) {
                ui.label(format!(
                    "selected #{mi}: src {} -> tgt {} · score {:.2} · {} · {}",
                    m.src,
                    m.tgt,
                    m.score,
                    m.branch.label(),
                    match m.inlier_gt {
                        Some(true) => "GT inlier",
                        Some(false) => "GT outlier",
                        None => "GT unknown",
                    }
                ));
            }
        }
    }

    /// A changed prompt whose generation is not cached: offers to run the generator.
    fn generation_missing_prompt(&self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        if let Some(p) = self.model.generation_missing.clone() {
            ui.colored_label(
                egui::Color32::from_rgb(230, 190, 60),
                format!("No cached generation for this prompt:\n“{p}”"),
            );
            if ui.button("Run the generator").clicked() {
                commands.push(Command::RunGenerator { prompt: p });
            }
            ui.separator();
        }
    }
}
