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
        let prefix = tabs::pairs::common_id_prefix(&self.model);
        ui.horizontal(|ui| {
            ui.strong("Pairs");
            if !prefix.is_empty() {
                ui.weak(format!("(ids after “{prefix}”)"));
            }
        });
        tabs::pairs::pairs_panel(
            ui,
            &self.model,
            &mut self.tabs.pairs,
            &mut self.ui_state.pair_sort,
            commands,
        );
        ui.separator();
        ui.strong("Correspondences");
        self.match_display_controls(ui);
        self.correspondence_summary(ui);
        ui.separator();
        self.generation_missing_prompt(ui, commands);
        self.image_branch_failed(ui, commands);
        self.settings_header(ui, commands);
        let scene = self.scene_specific_prompt();
        controls::controls_ui(ui, &mut self.params, &mut self.image_off, &scene, commands);
    }

    /// The current pair could not run the image branch asked for: its reason is the pair's
    /// error; one click runs the geometric branch alone instead (the WFM control then says so).
    fn image_branch_failed(&mut self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        let failed = self
            .model
            .current_pair
            .and_then(|i| self.model.pairs.get(i))
            .and_then(|p| match &p.status {
                model::PairStatus::Failed(why) => Some(why.clone()),
                _ => None,
            });
        let (Some(why), Some(_)) = (failed, self.params.image.as_ref()) else {
            return;
        };
        ui.colored_label(
            egui::Color32::from_rgb(240, 80, 70),
            format!("Not registered: {why}"),
        );
        if ui
            .button("Run geometry only")
            .on_hover_text("switch the image branch off (WFM: none) and register this pair")
            .clicked()
        {
            if let Some(ib) = self.params.image.take() {
                self.image_off = ib;
            }
            self.params.fusion.mode = crate::fusion::FusionMode::default_for(false, false);
            if self.params.fusion.selection == crate::fusion::Selection::default_for(true) {
                self.params.fusion.selection = crate::fusion::Selection::default_for(false);
            }
            commands.push(Command::ApplySettings(self.params.clone()));
        }
        ui.separator();
    }

    /// What the settings are: the demo's protocol while the demo is open, what is saved and
    /// where, and the reset.
    fn settings_header(&mut self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        ui.horizontal(|ui| {
            ui.strong("Settings");
            if let Some(tag) = &self.model.settings {
                ui.weak(format!("id {}", tag.id))
                    .on_hover_text(format!("the shown result's settings: {}", tag.summary));
            }
        });
        if let Some(note) = &self.model.demo_protocol {
            ui.colored_label(controls::STATUS_WARN, note);
        }
        let saved = match &self.settings_path {
            Some(p) => format!(
                "Saved on change to {}: the pipeline settings below (never the demo's \
                 protocol), the image branch's settings while it is off, the 3D view and \
                 match display options, the tab, the pair order and the last opened data. \
                 Options given to `cgenreg inspect` replace only the settings they name.",
                p.display()
            ),
            None => "Nothing is saved in this session (no settings file).".to_string(),
        };
        ui.weak("what is saved").on_hover_text(saved);
        if ui
            .button("Reset to the paper's defaults")
            .on_hover_text(format!(
                "{}; with a WFM: L = 50, m = 3, K = 4, Noisy-AND, mutual NN",
                model::settings_summary(&paper_defaults())
            ))
            .clicked()
        {
            self.reset_to_paper_defaults(commands);
        }
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
        let style = &mut self.ui_state.line_style;
        ui.add(egui::Slider::new(&mut style.width, LineStyle::WIDTH).text("line width"));
        ui.add(egui::Slider::new(&mut style.alpha, LineStyle::ALPHA).text("line opacity"));
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
                "GT inliers ({}): {inl} of {} matches ({:.1} %); {kept_inl} of {kept} kept",
                self.model.gt_inlier_label(),
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
