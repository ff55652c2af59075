//! The inspector application: its state, the frame's layout (side panel, tab bar and the
//! current tab, log bar), persistence and the worker's events. The panels it lays out live
//! in `side_panel.rs`, `central_panel.rs`, `log_bar.rs` and `open_ui.rs` (methods of [`App`]).

mod central_panel;
mod log_bar;
mod open_ui;
mod persist;
mod run;
mod side_panel;

use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver};
use std::sync::Arc;

use eframe::egui;
use serde::{Deserialize, Serialize};

use crate::dataset::open::classify_drop;
use crate::pipeline::params::{ImageBranchParams, RegisterParams};
use log_bar::short;

use super::channel::{
    spawn_worker, Command, LogLevel, OpenKind, Worker, WorkerEvent, WorkerHandle,
};
use super::model::{self, InspectorModel};
use super::pair_order::PairSort;
use super::state::{LineStyle, MatchColorMode, Panel, Shared, UiState};
use super::tabs::{self, TabContext, Tabs};
use super::{controls, file_browser, render3d, view3d};
pub use persist::{
    default_settings_path, load_persisted, save_persisted, startup_commands, Persisted,
};
pub use run::{run_gui, run_gui_configured, run_gui_with};

use tabs::views::ViewsState;
use view3d::{View3dPrefs, View3dState};

/// The paper's defaults, as `cgenreg register` takes them without options: the geometric
/// branch (FPFH, v = 5 cm, nearest neighbours, SC2-PCR); choosing a WFM adds the image branch
/// with L = 50, m = 3, K = 4, row softmax at tau = 0.1, Noisy-AND and mutual nearest
/// neighbours.
pub fn paper_defaults() -> RegisterParams {
    let mut p = RegisterParams::default();
    p.fusion.mode = crate::fusion::FusionMode::default_for(false, false);
    p.fusion.selection = crate::fusion::Selection::default_for(false);
    p
}

#[derive(Clone, Debug)]
pub struct LogLine {
    pub level: LogLevel,
    pub text: String,
    /// A command echoed for debugging: in the log only, never in the status line.
    pub echo: bool,
}

/// The smallest text the inspector draws (captions, matrix labels), in points at scale 1.
pub const MIN_TEXT_PX: f32 = 11.0;

/// Raises egui's small text style (about 9 px by default) to [`MIN_TEXT_PX`], in every theme.
fn legible_small_text(ctx: &egui::Context) {
    let small = |s: &egui::Style| {
        s.text_styles
            .get(&egui::TextStyle::Small)
            .is_some_and(|f| f.size < MIN_TEXT_PX)
    };
    if small(&ctx.global_style()) {
        ctx.all_styles_mut(|s| {
            if let Some(f) = s.text_styles.get_mut(&egui::TextStyle::Small) {
                f.size = MIN_TEXT_PX;
            }
        });
    }
}

/// Warnings and errors the status area keeps in view at most.
const STATUS_LINES: usize = 4;

/// What a native file dialog sends back: the kind asked for, and the paths (None: cancelled).
type DialogAnswer = Receiver<(OpenKind, Option<Vec<PathBuf>>)>;

/// The inspector application.
pub struct App {
    model: InspectorModel,
    model_gen: u64,
    scene_gen: u64,
    pub ui_state: UiState,
    /// What the controls edit and the worker runs: the pipeline's own parameters.
    pub params: RegisterParams,
    /// The image branch's parameters while it is off.
    pub image_off: ImageBranchParams,
    /// The 3D view shared by the 3D tab, the Views tab and the hypothesis browser.
    view3d: View3dState,
    /// The image views shared by the Views and Posterior tabs.
    views: ViewsState,
    /// Every tab with its own state.
    pub tabs: Tabs,
    worker: Option<WorkerHandle>,
    pub log: Vec<LogLine>,
    /// Warnings and errors kept in view (the status area) until dismissed.
    pub status: Vec<LogLine>,
    show_log: bool,
    /// The native dialog's answer channel and when it was opened.
    dialog: Option<(DialogAnswer, std::time::Instant)>,
    /// The in-app file browser, while open.
    pub browser: Option<file_browser::FileBrowser>,
    /// Open files with the in-app browser instead of the native dialog (set by the user, or
    /// when the native dialog turned out to be unavailable).
    pub builtin_browser: bool,
    settings_path: Option<PathBuf>,
    last_saved: Option<Persisted>,
    last_opened: Option<(OpenKind, Vec<PathBuf>)>,
    /// The settings' id and the parameters it was computed from.
    settings_id: Option<(RegisterParams, String)>,
    /// Native dialogs are refused in tests and headless rendering.
    pub allow_dialogs: bool,
}

impl App {
    /// `settings_path`: where settings persist (None: nothing is read or written).
    pub fn new(
        model: InspectorModel,
        worker: Option<WorkerHandle>,
        settings_path: Option<PathBuf>,
    ) -> Self {
        let mut app = Self {
            model,
            model_gen: view3d::next_id(),
            scene_gen: view3d::next_id(),
            ui_state: UiState::default(),
            params: RegisterParams::default(),
            image_off: ImageBranchParams::default(),
            view3d: View3dState::default(),
            views: ViewsState::default(),
            tabs: Tabs::default(),
            worker,
            log: Vec::new(),
            status: Vec::new(),
            show_log: false,
            dialog: None,
            browser: None,
            builtin_browser: std::env::var("CGENREG_FILE_DIALOG").as_deref() == Ok("builtin"),
            settings_path,
            last_saved: None,
            last_opened: None,
            settings_id: None,
            allow_dialogs: true,
        };
        if let Some(path) = app.settings_path.clone() {
            let (p, err) = load_persisted(&path);
            if let Some(e) = err {
                app.push_log(LogLevel::Warn, e);
            }
            app.apply_persisted(p.clone());
            app.last_saved = Some(p);
        }
        let scene = app.scene_specific_prompt();
        let ib = match app.params.image.as_mut() {
            Some(ib) => ib,
            None => &mut app.image_off,
        };
        if ib.prompt.scene.is_empty() {
            ib.prompt.scene = scene;
        }
        app
    }

    pub fn apply_persisted(&mut self, p: Persisted) {
        self.params = p.params;
        self.image_off = p.image_off;
        self.view3d.prefs = p.view3d;
        self.ui_state.match_mode = p.match_mode;
        self.ui_state.match_count = p.match_count;
        self.ui_state.line_style = p.line_style;
        self.ui_state.tab = p.tab;
        self.ui_state.pair_sort = p.pair_sort;
        self.last_opened = p.last_opened;
    }

    pub fn persisted(&self) -> Persisted {
        // the demo's protocol belongs to the demo: what was saved before stays saved
        let params = match (&self.model.demo_protocol, &self.last_saved) {
            (None, _) => self.params.clone(),
            (Some(_), Some(saved)) => saved.params.clone(),
            (Some(_), None) => paper_defaults(),
        };
        Persisted {
            params,
            image_off: self.image_off.clone(),
            view3d: self.view3d.prefs.clone(),
            match_mode: self.ui_state.match_mode,
            match_count: self.ui_state.match_count,
            line_style: self.ui_state.line_style,
            tab: self.ui_state.tab,
            pair_sort: self.ui_state.pair_sort,
            last_opened: self.last_opened.clone(),
        }
    }

    pub fn model(&self) -> &InspectorModel {
        &self.model
    }

    /// The id of the settings in force ([`model::SettingsTag`]), recomputed when they change.
    pub fn settings_id(&mut self) -> String {
        match &self.settings_id {
            Some((p, id)) if *p == self.params => id.clone(),
            _ => {
                let id = model::SettingsTag::of(&self.params).id;
                self.settings_id = Some((self.params.clone(), id.clone()));
                id
            }
        }
    }

    /// Back to the paper's defaults: the pipeline's parameters, the image branch's (kept for
    /// when a WFM is chosen) and the view options; the data stays open.
    pub fn reset_to_paper_defaults(&mut self, commands: &mut Vec<Command>) {
        self.params = paper_defaults();
        self.image_off = ImageBranchParams::default();
        self.view3d.prefs = View3dPrefs::default();
        let ui = UiState::default();
        self.ui_state.match_mode = ui.match_mode;
        self.ui_state.match_count = ui.match_count;
        self.ui_state.line_style = ui.line_style;
        self.ui_state.only_survivors = ui.only_survivors;
        self.ui_state.show_3d_below_views = ui.show_3d_below_views;
        commands.push(Command::ApplySettings(self.params.clone()));
    }

    /// Replaces the shown model (caches keyed on the generation are rebuilt; the 3D view keeps
    /// its camera and points when the clouds are the same).
    pub fn set_model(&mut self, model: InspectorModel) {
        let same_clouds = model.source == self.model.source && model.target == self.model.target;
        if !same_clouds {
            self.scene_gen = view3d::next_id();
        }
        // the selected match by identity (its keypoints): a re-fusion reorders the matches,
        // and an index would silently name another one
        let selected = self
            .ui_state
            .selected_match
            .and_then(|i| self.model.matches.get(i))
            .map(|m| (m.src, m.tgt))
            .filter(|_| same_clouds);
        self.model = model;
        self.model_gen = view3d::next_id();
        // a hypothesis indexes the old model's matches
        self.ui_state.hypothesis = None;
        self.ui_state.selected_match = selected.and_then(|(src, tgt)| {
            self.model
                .matches
                .iter()
                .position(|m| m.src == src && m.tgt == tgt)
        });
    }

    /// Turns the 3D camera (benchmarks and scripted screenshots).
    pub fn orbit_3d(&mut self, dx: f32, dy: f32) {
        self.view3d.camera.orbit(dx, dy);
    }

    /// Draw every point of a still 3D view in one frame (true: headless screenshots) or
    /// refine it over a few frames (false: the interactive default).
    pub fn set_complete_3d_frames(&mut self, on: bool) {
        self.view3d.complete_frames = on;
        self.tabs.posterior.view3d.complete_frames = on;
    }

    /// Points per cloud the 3D panel draws while its camera moves (adapted to the frame time).
    pub fn view3d_moving_budget(&self) -> u32 {
        self.view3d.moving_budget()
    }

    /// The 3D panel's last frame is not its final one (moving, settling or refining).
    pub fn view3d_refining(&self) -> bool {
        self.view3d.refining
    }

    pub fn view3d_prefs_mut(&mut self) -> &mut View3dPrefs {
        &mut self.view3d.prefs
    }

    /// The 3D panel's state (its camera, the distance tool, where points were drawn).
    pub fn view3d(&self) -> &View3dState {
        &self.view3d
    }

    /// Show the depth frames instead of the generated views in the views panel.
    pub fn show_depth_frames(&mut self, on: bool) {
        self.views.show_depth = on;
    }

    /// Shows view pair (source view, target view) in the views panel; None: the pair with
    /// the most shown matches.
    pub fn show_view_pair(&mut self, pair: Option<(usize, usize)>) {
        self.views.pair = pair;
    }

    /// The open data set's own scene description (its manifest's `scene_prompt`), or "" when
    /// it names none: the scene-specific preset then uses the pipeline's text.
    fn scene_specific_prompt(&self) -> String {
        self.model.scene_prompt.clone().unwrap_or_default()
    }

    pub fn push_log(&mut self, level: LogLevel, text: impl Into<String>) {
        let text = text.into();
        if level == LogLevel::Error {
            eprintln!("cgenreg: {text}");
        }
        let line = LogLine {
            level,
            text,
            echo: false,
        };
        if level != LogLevel::Info {
            // a warning stays in view until dismissed; the same text is not stacked twice
            self.status.retain(|l| l.text != line.text);
            self.status.push(line.clone());
            if self.status.len() > STATUS_LINES {
                self.status.remove(0);
            }
        }
        self.log.push(line);
        self.trim_log();
    }

    /// A command echoed to the log (debugging aid; never shown as the status).
    fn push_echo(&mut self, text: String) {
        self.log.push(LogLine {
            level: LogLevel::Info,
            text,
            echo: true,
        });
        self.trim_log();
    }

    fn trim_log(&mut self) {
        if self.log.len() > 2000 {
            self.log.drain(..500);
        }
    }

    fn send(&mut self, c: Command) {
        if let Command::Open { kind, paths } = &c {
            let k = match kind {
                OpenKind::Auto => classify_drop(paths),
                k => *k,
            };
            // a Cosmos output folder changes the image branch (persisted with the settings),
            // not the data
            if k != OpenKind::CosmosOutput {
                self.last_opened = Some((*kind, paths.clone()));
            }
        }
        let ok = self.worker.as_ref().map(|w| w.send(c.clone()));
        match ok {
            Some(true) => self.push_echo(format!("-> {}", short(&c))),
            Some(false) => self.push_log(
                LogLevel::Error,
                "the worker thread has stopped; command dropped",
            ),
            None => self.push_log(LogLevel::Info, format!("(no worker) {}", short(&c))),
        }
    }

    fn poll_worker(&mut self) {
        let events = self.worker.as_ref().map(|w| w.poll()).unwrap_or_default();
        for e in events {
            match e {
                WorkerEvent::Model(m) => self.set_model(*m),
                WorkerEvent::Stage(s) => {
                    if let Some(x) = self.model.stages.iter_mut().find(|x| x.name == s.name) {
                        *x = s;
                    } else {
                        self.model.stages.push(s);
                    }
                }
                WorkerEvent::Log(l, t) => self.push_log(l, t),
                WorkerEvent::Settings(s) => self.params = *s,
                WorkerEvent::RunAll(p) => {
                    tabs::pairs::apply_progress(&mut self.model, &mut self.tabs.pairs, p)
                }
                WorkerEvent::Compare(e) => {
                    for (level, text) in self.tabs.compare.on_event(e) {
                        self.push_log(level, text);
                    }
                }
                WorkerEvent::Progress(what, done, total) => {
                    self.model.plots.study_progress = (done < total).then_some((what, done, total));
                }
            }
        }
        if let Some((rx, started)) = &self.dialog {
            if let Ok((kind, paths)) = rx.try_recv() {
                let fast = started.elapsed() < open_ui::NO_DIALOG_WITHIN;
                self.dialog = None;
                match paths {
                    Some(paths) if !paths.is_empty() => self.open_paths(kind, paths),
                    // rfd answers None at once when it has neither a portal nor zenity
                    _ if fast => {
                        self.push_log(
                            LogLevel::Info,
                            "no native file dialog (no xdg portal or zenity): using the built-in browser",
                        );
                        self.builtin_browser = true;
                        self.open_browser(kind);
                    }
                    _ => self.push_log(LogLevel::Info, "open cancelled"),
                }
            }
        }
    }

    fn save_if_changed(&mut self) {
        let Some(path) = self.settings_path.clone() else {
            return;
        };
        let p = self.persisted();
        if self.last_saved.as_ref() != Some(&p) {
            if let Err(e) = save_persisted(&path, &p) {
                self.push_log(LogLevel::Warn, format!("settings not saved: {e}"));
                self.settings_path = None;
            }
            self.last_saved = Some(p);
        }
    }

    /// The whole UI, inside any `Ui` (eframe window, headless renderer, test harness).
    pub fn show(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        legible_small_text(&ctx);
        self.poll_worker();
        for (level, text) in self.tabs.compare.poll(&ctx) {
            self.push_log(level, text);
        }
        self.handle_drops(&ctx);
        self.tabs.pairs.current_settings = Some(self.settings_id());
        self.ui_state.begin_frame();
        let mut commands: Vec<Command> = Vec::new();
        let mut open_request: Option<OpenKind> = None;
        tabs::pairs::keyboard_nav(
            &ctx,
            &self.model,
            &mut self.tabs.pairs,
            self.ui_state.pair_sort,
            &mut commands,
        );

        egui::Panel::bottom("log_bar").show(ui, |ui| self.log_bar(ui));
        egui::Panel::left("controls")
            .default_size(300.0)
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical()
                    .id_salt("controls_scroll")
                    .show(ui, |ui| {
                        self.side_panel(ui, &mut commands, &mut open_request)
                    });
            });
        egui::CentralPanel::default().show(ui, |ui| self.central_panel(ui, &mut commands));
        if let Some(a) = self.tabs.compare.action.take() {
            self.compare_action(a, &mut commands, &mut open_request);
        }

        if let Some(k) = open_request {
            self.open_dialog(k, &ctx);
        }
        self.browser_outcome(&ctx, &mut commands);
        for c in commands {
            self.send(c);
        }
        open_ui::drop_overlay(&ctx);
        self.save_if_changed();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_selected_match_is_kept_by_its_keypoints_across_a_refusion() {
        let demo = InspectorModel::demo();
        let mut app = App::new(demo.clone(), None, None);
        let mi = 5;
        let (src, tgt) = (demo.matches[mi].src, demo.matches[mi].tgt);
        app.ui_state.selected_match = Some(mi);
        // a re-fusion: the same clouds, the matches in another order and one fewer
        let mut refused = demo.clone();
        refused.matches.reverse();
        refused.matches.remove(0);
        app.set_model(refused.clone());
        let now = app.ui_state.selected_match.expect("still selected");
        assert_ne!(now, mi, "the order changed, so must the index");
        let m = &app.model().matches[now];
        assert_eq!((m.src, m.tgt), (src, tgt));
        // the match is gone after the next re-fusion: nothing is selected
        let mut without = refused.clone();
        without.matches.retain(|m| (m.src, m.tgt) != (src, tgt));
        app.set_model(without);
        assert_eq!(app.ui_state.selected_match, None);
        // another pair (other clouds): keypoint indices name other points
        app.set_model(demo.clone());
        app.ui_state.selected_match = Some(mi);
        let mut other = demo;
        other.source.truncate(other.source.len() / 2);
        app.set_model(other);
        assert_eq!(app.ui_state.selected_match, None);
    }
}
