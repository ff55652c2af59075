//! The central area: the tab bar with the current pair's metrics, and the shown tab.

use super::*;

impl App {
    /// The tab bar, the convention warning and the current tab.
    pub(super) fn central_panel(&mut self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        self.tab_bar(ui);
        self.pair_header(ui);
        if let Some(p) = &self.model.preview_note {
            ui.colored_label(controls::STATUS_WARN, p);
        }
        if let Some(w) = &self.model.convention_warning {
            // next to the metrics: the GT they are computed against may be inverted
            ui.colored_label(egui::Color32::from_rgb(240, 150, 60), w);
        }
        if let Some(f) = &self.model.fusion_note {
            // which branch's pose the result is, and why
            ui.label(f);
        }
        if let Some(s) = &self.model.scale_note {
            // which scale hypothesis the result is, and each one's V
            ui.label(s);
        }
        ui.separator();
        self.current_tab(ui, commands);
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
                    if let Some(c) = &self.model.criteria_note {
                        ui.weak(c);
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

    fn current_tab(&mut self, ui: &mut egui::Ui, commands: &mut Vec<Command>) {
        let panel = self.ui_state.tab;
        let mut cx = TabContext {
            shared: Shared {
                model: &self.model,
                model_gen: self.model_gen,
                scene_gen: self.scene_gen,
                ui: &mut self.ui_state,
                commands,
            },
            view3d: &mut self.view3d,
            views: &mut self.views,
        };
        self.tabs.show(panel, ui, &mut cx);
    }
}
