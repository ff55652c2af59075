//! The Compare tab: two `cgenreg bench --json` runs over the same pairs, side by side. Which
//! pairs flipped from success to failure, by how much RRE / RTE moved, a scatter of RRE A
//! against RRE B, the four success quadrants as filters, and a pair opened in the inspector
//! with the settings of either run. Everything computed comes from
//! [`crate::report::compare`] (the same comparison as `cgenreg diff`); this file draws it.
//!
//! The two files are read off the UI thread ([`CompareTab::request`] starts a short-lived
//! loader thread, polled every frame): a merged run over a whole dataset is a large file, and
//! the pipeline worker may be busy for minutes (a study, Run all) when the user asks.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver};

use eframe::egui;

use super::{Tab, TabContext};
use crate::app::channel::{Command, LogLevel};
use crate::app::model::InspectorModel;
use crate::app::state::Panel;
use crate::report::compare::{self, Flip, PairOrder};

mod header;
mod load;
mod scatter;
pub mod settings_run;
mod table;

pub use crate::app::model::{CompareEvent, SettingsCompareRequest, SettingsRuns, Side};
pub use load::{load_comparison, LoadedComparison, LoadedRun};
pub use settings_run::SettingsCompare;

/// What the user asked for in the panel; the app carries it out.
#[derive(Clone, Debug, PartialEq)]
// One action per frame at most, returned and consumed at once: boxing `Send` buys nothing.
#[allow(clippy::large_enum_variant)]
pub enum CompareAction {
    /// Open `pair` in the inspector with the settings of run `side`.
    Open(Side, String),
    /// Open a run's manifest (the open dataset lacks the pair).
    OpenManifest(PathBuf),
    /// Choose two bench JSONs (the "Compare runs" file dialog / browser).
    Browse,
    /// Take the controls' settings as settings A or B of a comparison over the open dataset.
    TakeSettings(Side),
    /// Send a command to the worker (run or cancel a settings comparison).
    Send(Command),
}

/// Index of a flip in [`CompareTab::show`] and in the quadrant buttons.
fn flip_index(f: Flip) -> usize {
    match f {
        Flip::BothSuccess => 0,
        Flip::Lost => 1,
        Flip::Gained => 2,
        Flip::BothFailure => 3,
        Flip::Unknown => 4,
    }
}

const FLIPS: [Flip; 5] = [
    Flip::BothSuccess,
    Flip::Lost,
    Flip::Gained,
    Flip::BothFailure,
    Flip::Unknown,
];

/// Colour of a quadrant (points, counts, rows).
pub fn flip_color(f: Flip) -> egui::Color32 {
    match f {
        Flip::BothSuccess => egui::Color32::from_rgb(90, 190, 110),
        Flip::Lost => egui::Color32::from_rgb(240, 90, 80),
        Flip::Gained => egui::Color32::from_rgb(80, 160, 255),
        Flip::BothFailure => egui::Color32::from_rgb(150, 150, 150),
        Flip::Unknown => egui::Color32::from_rgb(200, 170, 90),
    }
}

fn flip_short(f: Flip) -> &'static str {
    match f {
        Flip::BothSuccess => "both succeed",
        Flip::Lost => "A only",
        Flip::Gained => "B only",
        Flip::BothFailure => "both fail",
        Flip::Unknown => "no GT",
    }
}

/// A load in progress: the loader thread's answer channel and the two files.
type Loading = (Receiver<Result<LoadedComparison, String>>, PathBuf, PathBuf);

/// The Compare tab's state: the loaded comparison, the loader thread, filters and sorting.
pub struct CompareTab {
    pub loaded: Option<LoadedComparison>,
    /// Paths asked for and not yet handed to a loader thread (started on the next frame).
    request: Option<(PathBuf, PathBuf)>,
    loading: Option<Loading>,
    /// Why the last load failed.
    pub error: Option<String>,
    /// Which quadrants the table and the scatter show (indexed by [`flip_index`]).
    pub show: [bool; 5],
    pub order: PairOrder,
    pub descending: bool,
    /// Log axes in the scatter (RRE spans 0.01° to 180°).
    pub log_axes: bool,
    /// The selected pair id.
    pub selected: Option<String>,
    /// Two settings compared over the open dataset.
    pub settings: SettingsCompare,
    /// What the user asked for this frame; the app takes it after drawing the tab.
    pub action: Option<CompareAction>,
}

impl Default for CompareTab {
    fn default() -> Self {
        Self {
            loaded: None,
            request: None,
            loading: None,
            error: None,
            show: [true; 5],
            order: PairOrder::FlippedFirst,
            descending: false,
            log_axes: true,
            selected: None,
            settings: SettingsCompare::default(),
            action: None,
        }
    }
}

impl CompareTab {
    /// Loads `a` and `b` off the UI thread (started on the next frame).
    pub fn request(&mut self, a: PathBuf, b: PathBuf) {
        self.request = Some((a, b));
        self.error = None;
    }

    /// A comparison loaded elsewhere (headless screenshots, tests).
    pub fn set_loaded(&mut self, l: LoadedComparison) {
        self.loaded = Some(l);
        self.error = None;
        self.selected = None;
    }

    /// True while files are asked for or being read.
    pub fn is_loading(&self) -> bool {
        self.request.is_some() || self.loading.is_some()
    }

    /// Starts a requested load and takes a finished one; returns lines for the log.
    pub fn poll(&mut self, ctx: &egui::Context) -> Vec<(LogLevel, String)> {
        let mut log = Vec::new();
        if let Some((a, b)) = self.request.take() {
            let (tx, rx) = channel();
            let (ta, tb, ctx2) = (a.clone(), b.clone(), ctx.clone());
            let spawned = std::thread::Builder::new()
                .name("cgenreg-compare".into())
                .spawn(move || {
                    let _ = tx.send(load_comparison(&ta, &tb));
                    ctx2.request_repaint();
                });
            match spawned {
                Ok(_) => self.loading = Some((rx, a, b)),
                Err(e) => {
                    let e = format!("could not start the loader thread: {e}");
                    log.push((LogLevel::Error, e.clone()));
                    self.error = Some(e);
                }
            }
        }
        if let Some((rx, a, b)) = &self.loading {
            match rx.try_recv() {
                Ok(Ok(l)) => {
                    let c = &l.comparison;
                    log.push((
                        LogLevel::Info,
                        format!(
                            "compared {} (A) and {} (B): {} pairs in both",
                            a.display(),
                            b.display(),
                            c.pairs.len()
                        ),
                    ));
                    self.loading = None;
                    self.set_loaded(l);
                }
                Ok(Err(e)) => {
                    log.push((LogLevel::Error, format!("compare runs: {e}")));
                    self.error = Some(e);
                    self.loading = None;
                }
                Err(std::sync::mpsc::TryRecvError::Empty) => {}
                Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                    let e = "compare runs: the loader thread ended without an answer".to_string();
                    log.push((LogLevel::Error, e.clone()));
                    self.error = Some(e);
                    self.loading = None;
                }
            }
        }
        log
    }

    /// The pairs shown, in the table's order (quadrant filters applied).
    pub fn rows(&self) -> Vec<usize> {
        let Some(l) = &self.loaded else {
            return Vec::new();
        };
        let c = &l.comparison;
        compare::order(c, self.order, self.descending)
            .into_iter()
            .filter(|&i| self.show[flip_index(c.pairs[i].flip)])
            .collect()
    }
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

fn fmt(v: Option<f64>, scale: f64, digits: usize) -> String {
    v.map(|x| format!("{:.*}", digits, x * scale))
        .unwrap_or_else(|| "-".into())
}

const WARN: egui::Color32 = egui::Color32::from_rgb(230, 190, 60);

/// Draws the Compare tab; returns what the user asked for.
impl Tab for CompareTab {
    fn panel(&self) -> Panel {
        Panel::Compare
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        self.action = compare_panel(ui, cx.shared.model, self);
    }
}

fn compare_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    st: &mut CompareTab,
) -> Option<CompareAction> {
    let mut action = None;
    ui.horizontal(|ui| {
        if ui
            .button("Compare runs...")
            .on_hover_text("choose two `cgenreg bench --json` outputs: run A, then run B")
            .clicked()
        {
            action = Some(CompareAction::Browse);
        }
        if st.is_loading() {
            ui.spinner();
            ui.label("reading the runs...");
        }
        if let Some(e) = &st.error {
            ui.colored_label(egui::Color32::from_rgb(240, 80, 70), e);
        }
    });
    let running = st.settings.progress.is_some();
    egui::CollapsingHeader::new("Compare two settings over the open dataset")
        .id_salt("compare_settings")
        .default_open(st.loaded.is_none())
        .open(running.then_some(true))
        .show(ui, |ui| {
            action = settings_run::settings_section(ui, model, &mut st.settings).or(action.take());
        });
    let Some(l) = &st.loaded else {
        ui.add_space(8.0);
        ui.label(
            "No runs compared yet. Load two `cgenreg bench --json` (or `cgenreg merge`) outputs \
             over the same pairs: \"Compare runs...\" above or in Open..., or start with \
             `cgenreg inspect --compare A.json B.json` (the table is the same as \
             `cgenreg diff A.json B.json`); or take settings A and B from the controls and run \
             both over the open dataset above.",
        );
        return action;
    };
    header::header(ui, l);
    ui.separator();
    quadrant_bar(ui, st);
    if let Some(a) = header::selected_pair(ui, model, st) {
        action = Some(a);
    }
    ui.separator();
    let rows = st.rows();
    let avail = ui.available_size();
    let side = (avail.x * 0.4).min(avail.y - 8.0).max(160.0);
    ui.horizontal_top(|ui| {
        ui.vertical(|ui| {
            ui.set_width(side);
            scatter::scatter(ui, st, &rows, side);
        });
        ui.separator();
        ui.vertical(|ui| table::table(ui, st, &rows));
    });
    action
}

/// The quadrant counts (each a filter of the table and the scatter), recalls and median
/// differences, and the pairs not in both runs.
fn quadrant_bar(ui: &mut egui::Ui, st: &mut CompareTab) {
    let Some(l) = &st.loaded else { return };
    let c = &l.comparison;
    ui.horizontal_wrapped(|ui| {
        ui.label(format!("{} pairs in both:", c.pairs.len()));
        let q = &c.quadrants;
        let counts = [
            q.both_success,
            q.only_a,
            q.only_b,
            q.both_failure,
            q.unknown,
        ];
        for f in FLIPS {
            let i = flip_index(f);
            if f == Flip::Unknown && counts[i] == 0 {
                continue;
            }
            let text = egui::RichText::new(format!("{}: {}", flip_short(f), counts[i]))
                .color(flip_color(f))
                .strong();
            if ui
                .selectable_label(st.show[i], text)
                .on_hover_text(format!("{}: show or hide these pairs", f.label()))
                .clicked()
            {
                st.show[i] = !st.show[i];
            }
        }
        if st.show.iter().any(|s| !s) && ui.small_button("all").clicked() {
            st.show = [true; 5];
        }
        ui.separator();
        ui.label(format!(
            "recall A {} %, B {} % | median dRRE {} deg, dRTE {} cm (B - A)",
            fmt(c.recall_a, 100.0, 1),
            fmt(c.recall_b, 100.0, 1),
            fmt(c.median_d_rre_deg, 1.0, 2),
            fmt(c.median_d_rte_m, 100.0, 2),
        ));
    });
    if !c.only_in_a.is_empty() || !c.only_in_b.is_empty() {
        ui.colored_label(
            WARN,
            format!(
                "not compared: {} pairs only in A, {} only in B",
                c.only_in_a.len(),
                c.only_in_b.len()
            ),
        );
    }
}
