//! The 3D tab: the 3D view's options row, then the viewport (the view itself, shared with the
//! Views tab and the hypothesis browser, is [`crate::app::view3d`]).

use eframe::egui;

use super::{Tab, TabContext};
use crate::app::state::Panel;
use crate::app::view3d::{scene_ui, view3d_options};

#[derive(Default)]
pub struct View3dTab;

impl Tab for View3dTab {
    fn panel(&self) -> Panel {
        Panel::View3d
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        view3d_options(ui, cx.view3d);
        scene_ui(ui, &mut cx.shared, cx.view3d, None);
    }
}
