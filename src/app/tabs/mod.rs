//! The central area's tabs, one file (or folder) each behind one contract, [`Tab`]: a tab
//! draws itself from the model and the shared UI state ([`TabContext`]), keeps its own
//! state in its own struct, and asks for work only by queueing commands.
//!
//! A new tab goes in three places: its file here (a struct implementing [`Tab`]), its
//! [`Panel`] variant (`app/state.rs`: label and command-line name) and its field in [`Tabs`]
//! (with its entry in [`Tabs::all_mut`]).

pub mod compare;
pub mod hypotheses;
pub mod pairs;
pub mod plots;
pub mod posterior;
pub mod stages;
pub mod view3d;
pub mod views;

use eframe::egui;

use super::state::{Panel, Shared};
use super::view3d::View3dState;
use views::ViewsState;

/// What every tab gets each frame besides its own state.
pub struct TabContext<'a> {
    /// The model (read-only), the shared UI state and this frame's command queue.
    pub shared: Shared<'a>,
    /// The 3D view (camera, uploaded clouds), one for the 3D tab, the Views tab's "3D view
    /// below" and the hypothesis browser, so the camera stays where the user left it.
    pub view3d: &'a mut View3dState,
    /// The image views (view pair shown, zoom), shared by the Views and Posterior tabs.
    pub views: &'a mut ViewsState,
}

/// One tab of the central area.
pub trait Tab {
    /// Which tab this is (its label, command-line name and saved value).
    fn panel(&self) -> Panel;
    /// Draws the tab into `ui` (the area below the tab bar).
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>);
}

/// Every tab with its own state.
#[derive(Default)]
pub struct Tabs {
    pub pairs: pairs::PairsTab,
    pub views: views::ViewsTab,
    pub view3d: view3d::View3dTab,
    pub posterior: posterior::PosteriorTab,
    pub plots: plots::PlotsTab,
    pub stages: stages::StagesTab,
    pub compare: compare::CompareTab,
    pub hypotheses: hypotheses::HypothesesTab,
}

impl Tabs {
    /// Every tab, in no particular order (the tab bar follows [`Panel::ALL`]).
    pub fn all_mut(&mut self) -> [&mut dyn Tab; 8] {
        [
            &mut self.pairs,
            &mut self.views,
            &mut self.view3d,
            &mut self.posterior,
            &mut self.plots,
            &mut self.stages,
            &mut self.compare,
            &mut self.hypotheses,
        ]
    }

    /// Draws the tab of `panel`.
    pub fn show(&mut self, panel: Panel, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        if let Some(tab) = self.all_mut().into_iter().find(|t| t.panel() == panel) {
            tab.ui(ui, cx);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_panel_has_exactly_one_tab() {
        let mut tabs = Tabs::default();
        let mut panels: Vec<Panel> = tabs.all_mut().iter().map(|t| t.panel()).collect();
        for p in Panel::ALL {
            let n = panels.iter().filter(|&&q| q == p).count();
            assert_eq!(n, 1, "{p:?} is drawn by {n} tabs");
        }
        panels.dedup();
        assert_eq!(panels.len(), Panel::ALL.len());
    }
}
