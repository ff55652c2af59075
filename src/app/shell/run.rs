//! The native window: the inspector inside eframe, saving its settings on exit.

use super::*;

struct EframeApp(App);

impl eframe::App for EframeApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.0.show(ui);
    }
    fn on_exit(&mut self, _gl: Option<&eframe::glow::Context>) {
        // the GL context is still current here; free the 3D buffers before it goes
        render3d::release_gl(None);
    }
}

/// Opens the inspector window (blocks until it is closed).
pub fn run_gui(model: InspectorModel, worker: Box<dyn Worker>) -> Result<(), String> {
    run_gui_with(model, worker, Vec::new(), None)
}

/// [`run_gui`], sending `initial` commands to the worker once it runs (e.g. the pair to load).
///
/// One set of pipeline settings is in force, and the controls show it: `worker_settings`
/// (what the worker was started with, e.g. from command-line options) when given, else the
/// persisted settings, which are then sent to the worker before `initial`.
pub fn run_gui_with(
    model: InspectorModel,
    worker: Box<dyn Worker>,
    initial: Vec<Command>,
    worker_settings: Option<RegisterParams>,
) -> Result<(), String> {
    run_gui_configured(model, worker, initial, worker_settings, |_| {})
}

/// [`run_gui_with`], with the app configured before the first frame (e.g. two runs to
/// compare, [`App::compare_runs`]).
pub fn run_gui_configured(
    model: InspectorModel,
    worker: Box<dyn Worker>,
    initial: Vec<Command>,
    worker_settings: Option<RegisterParams>,
    configure: impl FnOnce(&mut App) + 'static,
) -> Result<(), String> {
    let options = eframe::NativeOptions {
        renderer: eframe::Renderer::Glow,
        depth_buffer: 24,
        viewport: egui::ViewportBuilder::default()
            .with_inner_size([1400.0, 900.0])
            .with_title("C-GenReg inspector")
            .with_drag_and_drop(true),
        ..Default::default()
    };
    eframe::run_native(
        "cgenreg inspector",
        options,
        Box::new(move |cc| {
            // a missing glyph (e.g. in a user's prompt) must draw a box, never abort
            cc.egui_ctx
                .set_missing_glyph_policy(egui::MissingGlyphPolicy::Tofu);
            let handle = spawn_worker(worker, Some(cc.egui_ctx.clone()));
            let mut app = App::new(model, None, default_settings_path());
            match worker_settings {
                Some(s) => app.params = s,
                None => {
                    handle.send(Command::ApplySettings(app.params.clone()));
                }
            }
            for c in initial {
                handle.send(c);
            }
            app.worker = Some(handle);
            configure(&mut app);
            Ok(Box::new(EframeApp(app)))
        }),
    )
    .map_err(|e| format!("could not open the inspector window: {e}"))
}
