//! The Compare tab: two `cgenreg bench --json` runs over the same pairs, side by side. Which
//! pairs flipped from success to failure, by how much RRE / RTE moved, a scatter of RRE A
//! against RRE B, the four success quadrants as filters, and a pair opened in the inspector
//! with the settings of either run. Everything computed comes from
//! [`crate::metrics::compare`] (the same comparison as `cgenreg diff`); this file draws it.
//!
//! The two files are read off the UI thread ([`CompareState::request`] starts a short-lived
//! loader thread, polled every frame): a merged run over a whole dataset is a large file, and
//! the pipeline worker may be busy for minutes (a study, Run all) when the user asks.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver};

use eframe::egui;
use egui_plot::{
    GridInput, GridMark, HLine, Legend, Line, LineStyle, Plot, PlotPoint, Points, VLine,
};

use super::controls::LogLevel;
use super::model::InspectorModel;
use crate::metrics::compare::{
    self, compare, load_bench_run, BenchRun, Comparison, Flip, PairDiff, PairOrder,
};
use crate::pipeline::params::RegisterParams;

/// One of the two runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    A,
    B,
}

impl Side {
    pub fn label(self) -> &'static str {
        match self {
            Side::A => "A",
            Side::B => "B",
        }
    }
}

/// One run as the panel shows it.
#[derive(Clone, Debug)]
pub struct LoadedRun {
    pub path: PathBuf,
    pub run: BenchRun,
    /// The run's parameters as the pipeline's type, or why they cannot be rebuilt.
    pub params: Result<RegisterParams, String>,
    /// The run's manifest, found here (see [`BenchRun::resolve_manifest`]).
    pub manifest: Option<PathBuf>,
    /// "FPFH (voxel 5 cm) | no image branch | Geometry only | NN | SC2-PCR".
    pub summary: String,
    /// Files the settings name that are missing here (e.g. the VFM model of another machine).
    pub missing: Vec<PathBuf>,
}

/// Two runs and their comparison.
#[derive(Clone, Debug)]
pub struct LoadedComparison {
    pub a: LoadedRun,
    pub b: LoadedRun,
    pub comparison: Comparison,
}

impl LoadedComparison {
    pub fn run(&self, side: Side) -> &LoadedRun {
        match side {
            Side::A => &self.a,
            Side::B => &self.b,
        }
    }
}

fn loaded_run(path: &Path) -> Result<LoadedRun, String> {
    let run = load_bench_run(path).map_err(|e| e.to_string())?;
    let params = run
        .register_params()
        .map_err(|e| format!("{}: {e}", path.display()));
    let missing = params
        .as_ref()
        .map(compare::missing_files)
        .unwrap_or_default();
    Ok(LoadedRun {
        path: path.to_path_buf(),
        manifest: run.resolve_manifest(path),
        summary: run.settings_summary(),
        params,
        missing,
        run,
    })
}

/// Reads two bench JSONs and compares them (B against A). Errors name the file and the field.
pub fn load_comparison(a: &Path, b: &Path) -> Result<LoadedComparison, String> {
    let a = loaded_run(a)?;
    let b = loaded_run(b)?;
    let comparison = compare(&a.run, &b.run);
    Ok(LoadedComparison { a, b, comparison })
}

/// What the user asked for in the panel; the app carries it out.
#[derive(Clone, Debug, PartialEq)]
pub enum CompareAction {
    /// Open `pair` in the inspector with the settings of run `side`.
    Open(Side, String),
    /// Open a run's manifest (the open dataset lacks the pair).
    OpenManifest(PathBuf),
    /// Choose two bench JSONs (the "Compare runs" file dialog / browser).
    Browse,
}

/// Index of a flip in [`CompareState::show`] and in the quadrant buttons.
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
pub struct CompareState {
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
}

impl Default for CompareState {
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
        }
    }
}

impl CompareState {
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
pub fn compare_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    st: &mut CompareState,
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
    let Some(l) = &st.loaded else {
        ui.add_space(8.0);
        ui.label(
            "No runs compared yet. Load two `cgenreg bench --json` (or `cgenreg merge`) outputs \
             over the same pairs: \"Compare runs...\" above or in Open..., or start with \
             `cgenreg inspect --compare A.json B.json`. The table is the same as \
             `cgenreg diff A.json B.json`.",
        );
        return action;
    };
    let c = &l.comparison;
    header(ui, l);
    ui.separator();
    // quadrant counts as filters
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
    if let Some(a) = selected_pair(ui, model, st) {
        action = Some(a);
    }
    ui.separator();
    let rows = st.rows();
    let avail = ui.available_size();
    let side = (avail.x * 0.4).min(avail.y - 8.0).max(160.0);
    ui.horizontal_top(|ui| {
        ui.vertical(|ui| {
            ui.set_width(side);
            scatter(ui, st, &rows, side);
        });
        ui.separator();
        ui.vertical(|ui| table(ui, st, &rows));
    });
    action
}

fn header(ui: &mut egui::Ui, l: &LoadedComparison) {
    let c = &l.comparison;
    egui::Grid::new("compare_header")
        .num_columns(3)
        .spacing([12.0, 2.0])
        .show(ui, |ui| {
            for side in [Side::A, Side::B] {
                let r = l.run(side);
                ui.strong(format!("run {}", side.label()));
                ui.label(egui::RichText::new(file_name(&r.path)).strong())
                    .on_hover_text(r.path.display().to_string());
                ui.label(&r.summary);
                ui.end_row();
            }
        });
    match c.differing_settings.len() {
        0 => {
            ui.label("parameters: identical");
        }
        1 => {
            ui.label(format!(
                "the runs differ only in: {}",
                c.differing_settings[0]
            ));
        }
        n => {
            ui.colored_label(
                WARN,
                format!(
                    "the runs differ in {n} settings, not only the one compared: {}",
                    c.differing_settings.join(", ")
                ),
            );
        }
    }
    if !c.param_differences.is_empty() || !c.run_differences.is_empty() {
        egui::CollapsingHeader::new(format!(
            "what differs ({} values)",
            c.param_differences.len() + c.run_differences.len()
        ))
        .id_salt("compare_differences")
        .show(ui, |ui| {
            for d in &c.param_differences {
                ui.label(format!("params.{d}"));
            }
            for d in &c.run_differences {
                ui.label(format!("run: {d}"));
            }
        });
    }
    for side in [Side::A, Side::B] {
        let r = l.run(side);
        if let Err(e) = &r.params {
            ui.colored_label(
                WARN,
                format!(
                    "run {}: its settings cannot be rebuilt ({e}); \"open with {}\" is off",
                    side.label(),
                    side.label()
                ),
            );
        }
        for m in &r.missing {
            ui.colored_label(
                WARN,
                format!(
                    "run {}: {} is not on this machine; opening a pair with its settings fails \
                     where that file is needed",
                    side.label(),
                    m.display()
                ),
            );
        }
    }
}

/// The selected pair's line: both runs' numbers and the open buttons.
fn selected_pair(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    st: &CompareState,
) -> Option<CompareAction> {
    let l = st.loaded.as_ref()?;
    let mut action = None;
    ui.horizontal_wrapped(|ui| {
        let Some(p) = st
            .selected
            .as_ref()
            .and_then(|id| l.comparison.pairs.iter().find(|p| &p.id == id))
        else {
            ui.weak(
                "click a pair in the table or the scatter to open it with run A's or B's settings",
            );
            return;
        };
        ui.label(egui::RichText::new(&p.id).strong());
        ui.colored_label(flip_color(p.flip), p.flip.label());
        ui.label(format!(
            "RRE {} / {} deg, RTE {} / {} cm (A / B)",
            fmt(p.a.rre_deg, 1.0, 2),
            fmt(p.b.rre_deg, 1.0, 2),
            fmt(p.a.rte_m, 100.0, 1),
            fmt(p.b.rte_m, 100.0, 1)
        ));
        let in_dataset = model.pairs.iter().any(|e| e.id == p.id);
        for side in [Side::A, Side::B] {
            let r = l.run(side);
            let button = ui.add_enabled(
                r.params.is_ok() && in_dataset,
                egui::Button::new(format!("open with {}", side.label())),
            );
            let button = match &r.params {
                Ok(_) => button.on_hover_text(format!(
                    "register {} with run {}'s settings ({})",
                    p.id,
                    side.label(),
                    r.summary
                )),
                Err(e) => button.on_disabled_hover_text(e.clone()),
            };
            if button.clicked() {
                action = Some(CompareAction::Open(side, p.id.clone()));
            }
        }
        if !in_dataset {
            match l.a.manifest.as_ref().or(l.b.manifest.as_ref()) {
                Some(m) => {
                    ui.colored_label(WARN, "not in the open dataset:");
                    if ui
                        .button(format!("open {}", file_name(m)))
                        .on_hover_text(m.display().to_string())
                        .clicked()
                    {
                        action = Some(CompareAction::OpenManifest(m.clone()));
                    }
                }
                None => {
                    ui.colored_label(
                        WARN,
                        format!(
                            "not in the open dataset, and the runs' manifest ({}) is not found \
                             here: open it with Open...",
                            l.a.run.manifest.as_deref().unwrap_or("not recorded")
                        ),
                    );
                }
            }
        }
    });
    action
}

/// Smallest RRE drawn on log axes (0.001 deg); smaller values sit on it.
const LOG_FLOOR: f64 = 1e-3;

fn axis_value(v: f64, log: bool) -> f64 {
    if log {
        v.max(LOG_FLOOR).log10()
    } else {
        v
    }
}

/// Grid lines at powers of ten (labelled) and at 2..9 times them (thin).
fn log_marks(input: GridInput) -> Vec<GridMark> {
    let (lo, hi) = input.bounds;
    let mut out = Vec::new();
    if !(lo.is_finite() && hi.is_finite()) || hi - lo > 40.0 {
        return out;
    }
    // marks inside the visible range only (a label at the edge is drawn outside the plot)
    let mut e = lo.floor();
    while e <= hi.ceil() {
        if e >= lo && e <= hi {
            out.push(GridMark {
                value: e,
                step_size: 1.0,
            });
        }
        for k in 2..10 {
            let v = e + (k as f64).log10();
            if v >= lo && v <= hi {
                out.push(GridMark {
                    value: v,
                    step_size: 0.1,
                });
            }
        }
        e += 1.0;
    }
    out
}

fn log_label(mark: GridMark) -> String {
    if (mark.value - mark.value.round()).abs() > 1e-9 {
        return String::new();
    }
    let v = 10f64.powf(mark.value.round());
    if v >= 1.0 {
        format!("{v:.0}")
    } else {
        format!("{v}")
    }
}

fn scatter(ui: &mut egui::Ui, st: &mut CompareState, rows: &[usize], side: f32) {
    let Some(l) = &st.loaded else { return };
    let c = &l.comparison;
    let log = st.log_axes;
    ui.horizontal(|ui| {
        ui.strong("RRE A against RRE B (deg)");
        ui.checkbox(&mut st.log_axes, "log axes");
    });
    let pts: Vec<(&PairDiff, f64, f64)> = rows
        .iter()
        .map(|&i| &c.pairs[i])
        .filter_map(|p| Some((p, p.a.rre_deg?, p.b.rre_deg?)))
        .map(|(p, x, y)| (p, axis_value(x, log), axis_value(y, log)))
        .collect();
    let unplotted = rows.len() - pts.len();
    let thr = axis_value(crate::metrics::RECALL_RRE_DEG, log);
    let (mut lo, mut hi) = (thr, thr);
    for &(_, x, y) in &pts {
        lo = lo.min(x).min(y);
        hi = hi.max(x).max(y);
    }
    let pad = if log { 0.2 } else { (hi - lo) * 0.05 + 1.0 };
    let (lo, hi) = (if log { lo - pad } else { 0f64.min(lo) }, hi + pad);
    let h = side - 40.0 - if unplotted > 0 { 18.0 } else { 0.0 };
    let mut plot = Plot::new("compare_scatter")
        .width(side)
        .height(h.max(120.0))
        .legend(Legend::default().position(egui_plot::Corner::LeftTop))
        .x_axis_label("RRE A (deg)")
        .y_axis_label("RRE B (deg)")
        .include_x(lo)
        .include_x(hi)
        .include_y(lo)
        .include_y(hi)
        .allow_scroll(false)
        .show_x(false)
        .show_y(false);
    if log {
        plot = plot
            .x_grid_spacer(log_marks)
            .y_grid_spacer(log_marks)
            .x_axis_formatter(|m, _| log_label(m))
            .y_axis_formatter(|m, _| log_label(m));
    }
    let selected = st.selected.clone();
    let resp = plot.show(ui, |p| {
        p.line(
            Line::new("A = B", vec![[lo, lo], [hi, hi]])
                .color(egui::Color32::from_gray(170))
                .allow_hover(false),
        );
        let thr_color = egui::Color32::from_rgb(230, 190, 60);
        p.vline(
            VLine::new("15 deg (success)", thr)
                .color(thr_color)
                .style(LineStyle::dashed_loose())
                .allow_hover(false),
        );
        p.hline(
            HLine::new("15 deg (success)", thr)
                .color(thr_color)
                .style(LineStyle::dashed_loose())
                .allow_hover(false),
        );
        for f in FLIPS {
            let xy: Vec<[f64; 2]> = pts
                .iter()
                .filter(|(q, _, _)| q.flip == f)
                .map(|&(_, x, y)| [x, y])
                .collect();
            if xy.is_empty() {
                continue;
            }
            p.points(
                Points::new(flip_short(f), xy)
                    .color(flip_color(f))
                    .radius(if matches!(f, Flip::Lost | Flip::Gained) {
                        4.5
                    } else {
                        3.0
                    })
                    .filled(true)
                    .allow_hover(false),
            );
        }
        if let Some((_, x, y)) = pts
            .iter()
            .find(|(q, _, _)| Some(&q.id) == selected.as_ref())
        {
            p.points(
                Points::new("selected", vec![[*x, *y]])
                    .color(egui::Color32::WHITE)
                    .radius(8.0)
                    .filled(false)
                    .allow_hover(false),
            );
        }
    });
    // the pair under the pointer (nearest point within 8 px)
    let hovered = resp.response.hover_pos().and_then(|pos| {
        pts.iter()
            .map(|(q, x, y)| {
                let s = resp.transform.position_from_point(&PlotPoint::new(*x, *y));
                (q, s.distance(pos))
            })
            .filter(|(_, d)| *d <= 8.0)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(q, _)| *q)
    });
    if let Some(q) = hovered {
        let text = format!(
            "{}\n{}\nRRE A {} deg, B {} deg",
            q.id,
            q.flip.label(),
            fmt(q.a.rre_deg, 1.0, 2),
            fmt(q.b.rre_deg, 1.0, 2)
        );
        let r = resp.response.clone().on_hover_text_at_pointer(text);
        if r.clicked() {
            st.selected = Some(q.id.clone());
        }
    }
    if unplotted > 0 {
        ui.weak(format!(
            "{unplotted} shown pairs lack an RRE in one run (failed to run): in the table only"
        ));
    }
    ui.weak(format!(
        "success: RRE <= {} deg and RTE <= {} cm",
        crate::metrics::RECALL_RRE_DEG,
        crate::metrics::RECALL_RTE_M * 100.0
    ));
}

/// Column widths of the table (pixels); the six number columns share what is left.
const ID_W: f32 = 140.0;
const FLAG_W: f32 = 30.0;

fn table(ui: &mut egui::Ui, st: &mut CompareState, rows: &[usize]) {
    let Some(l) = &st.loaded else { return };
    let c = &l.comparison;
    let gap = ui.spacing().item_spacing.x;
    let num_w =
        ((ui.available_width() - ID_W - 2.0 * FLAG_W - 9.0 * gap - 12.0) / 6.0).clamp(38.0, 70.0);
    let cols: [(&str, PairOrder, f32); 9] = [
        ("pair", PairOrder::Id, ID_W),
        ("A", PairOrder::Flip, FLAG_W),
        ("B", PairOrder::Flip, FLAG_W),
        ("RRE A", PairOrder::RreA, num_w),
        ("RRE B", PairOrder::RreB, num_w),
        ("dRRE", PairOrder::DRre, num_w),
        ("RTE A", PairOrder::RteA, num_w),
        ("RTE B", PairOrder::RteB, num_w),
        ("dRTE", PairOrder::DRte, num_w),
    ];
    ui.horizontal(|ui| {
        ui.strong(format!("{} pairs shown", rows.len()));
        if ui
            .selectable_label(st.order == PairOrder::FlippedFirst, "flipped first")
            .on_hover_text("gained or lost pairs first, then by |dRRE|")
            .clicked()
        {
            st.order = PairOrder::FlippedFirst;
            st.descending = false;
        }
        ui.weak("RRE in deg, RTE in cm, d = B - A; click a header to sort");
    });
    let mut sort_click = None;
    ui.horizontal(|ui| {
        for (i, (name, order, w)) in cols.iter().enumerate() {
            // the two status columns sort together; mark only the first
            let mark = if st.order == *order && i != 2 {
                if st.descending {
                    " v"
                } else {
                    " ^"
                }
            } else {
                ""
            };
            let r = ui.add_sized(
                [*w, 18.0],
                egui::Button::new(egui::RichText::new(format!("{name}{mark}")).strong())
                    .frame(false),
            );
            if r.clicked() {
                sort_click = Some(*order);
            }
        }
    });
    if let Some(o) = sort_click {
        if st.order == o {
            st.descending = !st.descending;
        } else {
            st.order = o;
            // errors: largest first
            st.descending = !matches!(o, PairOrder::Id | PairOrder::Flip);
        }
    }
    let row_h = ui.spacing().interact_size.y;
    let mut clicked = None;
    egui::ScrollArea::vertical()
        .id_salt("compare_table")
        .auto_shrink([false, false])
        .show_rows(ui, row_h, rows.len(), |ui, range| {
            for &i in &rows[range] {
                let p = &c.pairs[i];
                ui.horizontal(|ui| {
                    let sel = st.selected.as_deref() == Some(p.id.as_str());
                    let id = egui::RichText::new(&p.id).color(flip_color(p.flip));
                    if ui
                        .add_sized([ID_W, row_h], egui::Button::selectable(sel, id))
                        .on_hover_text(p.flip.label())
                        .clicked()
                    {
                        clicked = Some(p.id.clone());
                    }
                    for r in [&p.a, &p.b] {
                        let (t, col) = match (r.success, &r.error) {
                            (_, Some(e)) if !e.is_empty() => {
                                ("err", egui::Color32::from_rgb(240, 80, 70))
                            }
                            (Some(true), _) => ("ok", flip_color(Flip::BothSuccess)),
                            (Some(false), _) => ("fail", flip_color(Flip::Lost)),
                            (None, _) => ("-", egui::Color32::GRAY),
                        };
                        let cell = ui.add_sized(
                            [FLAG_W, row_h],
                            egui::Label::new(egui::RichText::new(t).color(col)),
                        );
                        if let Some(e) = &r.error {
                            cell.on_hover_text(e);
                        }
                    }
                    for (v, scale, d) in [
                        (p.a.rre_deg, 1.0, 2),
                        (p.b.rre_deg, 1.0, 2),
                        (p.d_rre_deg, 1.0, 2),
                        (p.a.rte_m, 100.0, 1),
                        (p.b.rte_m, 100.0, 1),
                        (p.d_rte_m, 100.0, 1),
                    ] {
                        ui.add_sized([num_w, row_h], egui::Label::new(fmt(v, scale, d)));
                    }
                });
            }
        });
    if let Some(id) = clicked {
        st.selected = Some(id);
    }
}
