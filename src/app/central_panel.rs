//! The central area: the tab bar with the current pair's metrics, and the shown tab.

use super::*;

impl App {
    /// The tab bar, the convention warning and the current tab. Returns what the Compare tab
    /// asked for.
    pub(super) fn central_panel(
        &mut self,
        ui: &mut egui::Ui,
        commands: &mut Vec<Command>,
    ) -> Option<compare_panel::CompareAction> {
        self.tab_bar(ui);
        self.pair_header(ui);
        if let Some(w) = &self.model.convention_warning {
            // next to the metrics: the GT they are computed against may be inverted
            ui.colored_label(egui::Color32::from_rgb(240, 150, 60), w);
        }
        if let Some(f) = &self.model.fusion_note {
            // which branch's pose the result is, and why
            ui.label(f);
        }
        ui.separator();
        self.current_tab(ui, commands)
    }

    /// One button per tab, then the current pair's name, RRE and RTE.
    fn tab_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            for p in Panel::ALL {
                ui.selectable_value(&mut self.ui_state.tab, p, p.label());
            }
            ui.separator();
            if let Some(pi) = self.model.current_pair {
                if let Some(p) = self.model.pairs.get(pi) {
                    ui.label(egui::RichText::new(&p.id).strong());
                    if let (Some(r), Some(t)) = (p.rre_deg, p.rte_m) {
                        ui.label(format!("RRE {r:.2}° · RTE {:.1} cm", t * 100.0));
                    }
                }
            }
        });
    }

    /// Which branches actually ran for the shown result, and whether its settings are the
    /// ones in force.
    fn pair_header(&mut self, ui: &mut egui::Ui) {
        let current = self.settings_id();
        let Some(ran) = &self.model.branches_ran else {
            return;
        };
        ui.horizontal_wrapped(|ui| {
            ui.label(ran);
            if let Some(tag) = &self.model.settings {
                if tag.id != current {
                    ui.colored_label(
                        controls::STATUS_WARN,
                        format!("stale: computed with other settings ({})", tag.summary),
                    );
                } else {
                    ui.weak(format!("settings {}", tag.id))
                        .on_hover_text(&tag.summary);
                }
            }
        });
    }

    fn current_tab(
        &mut self,
        ui: &mut egui::Ui,
        commands: &mut Vec<Command>,
    ) -> Option<compare_panel::CompareAction> {
        let mut shared = Shared {
            model: &self.model,
            model_gen: self.model_gen,
            scene_gen: self.scene_gen,
            ui: &mut self.ui_state,
            commands,
        };
        match shared.ui.tab {
            Panel::Pairs => pairs_panel::pairs_tab(
                ui,
                shared.model,
                &mut self.pairs,
                &mut shared.ui.pair_sort,
                shared.commands,
            ),
            Panel::Views => {
                ui.checkbox(&mut shared.ui.show_3d_below_views, "3D view below");
                let h = ui.available_height();
                if shared.ui.show_3d_below_views {
                    views_panel::views_panel(ui, &mut shared, &mut self.views, h * 0.62);
                    view3d::scene_ui(ui, &mut shared, &mut self.view3d, None);
                } else {
                    views_panel::views_panel(ui, &mut shared, &mut self.views, h);
                }
            }
            Panel::View3d => view3d::view3d_panel(ui, &mut shared, &mut self.view3d),
            Panel::Posterior => posterior_panel::posterior_panel(
                ui,
                &mut shared,
                &mut self.views,
                &mut self.posterior,
            ),
            Panel::Plots => {
                plots_panel::plots_panel(ui, shared.model, &mut self.plots, shared.commands)
            }
            Panel::Hypotheses => hypotheses_panel::hypotheses_panel(
                ui,
                &mut shared,
                &mut self.hypotheses,
                &mut self.view3d,
            ),
            Panel::Stages => {
                stages_panel::stages_panel(ui, shared.model, &mut self.stages, shared.commands)
            }
            Panel::Compare => {
                return compare_panel::compare_panel(ui, shared.model, &mut self.compare)
            }
        }
        None
    }
}
