//! The inspector GUI (eframe + glow, three-d inside egui panels, egui_plot).
//!
//! The UI reads an [`InspectorModel`] (plain data) every frame and never computes pipeline
//! results: control changes become [`Command`]s for a [`Worker`] thread, whose
//! [`WorkerEvent`]s replace the model, update stages and fill the log.
//!
//! Modules import only those below them, never upwards (a test in `tests/it` checks it):
//! `model` (plain data); `channel` (commands, events, the worker handle); the leaves
//! `colormap`, `path_display`, `pair_order`, `triage`, `file_browser`, `render3d`; `state` (what the
//! panels share); `controls` and `view3d` (widgets); `tabs` (one file per tab behind
//! [`tabs::Tab`]); `shell` (the [`App`]: side panel, tab bar, log, files) and `headless`.
//! The pipeline side, `worker`, imports only `model` and `channel`.

pub mod channel;
pub mod colormap;
pub mod controls;
pub mod file_browser;
pub mod headless;
pub mod model;
pub mod pair_order;
pub mod path_display;
pub mod render3d;
pub mod shell;
pub mod state;
pub mod tabs;
pub mod triage;
pub mod view3d;
pub mod worker;

pub use channel::{
    spawn_worker, Command, EventSink, LogLevel, LogOnlyWorker, OpenKind, StudyRequest, Worker,
    WorkerEvent, WorkerHandle,
};
pub use model::InspectorModel;
pub use shell::{
    default_settings_path, load_persisted, paper_defaults, run_gui, run_gui_configured,
    run_gui_with, save_persisted, startup_commands, App, LogLine, Persisted, MIN_TEXT_PX,
};
pub use state::{MatchColorMode, Panel, Shared, UiState};
