//! Pipeline controls and the channel to the worker that re-runs the pipeline.
//!
//! The UI never computes: every change of a control produces a [`Command`] sent over a
//! `std::sync::mpsc` channel to a worker thread, which answers with [`WorkerEvent`]s. The
//! lead implements [`Worker`] on top of the pipeline; [`spawn_worker`] runs it.

use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};

use eframe::egui;
use serde::{Deserialize, Serialize};

use super::model::{InspectorModel, StageInfo};

/// The four prompt presets of the prompt study (project page ablation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PromptPreset {
    /// The per-pair scene description from the spec file.
    SceneSpecific,
    General,
    Minimal,
    /// A deliberately wrong description (robustness study).
    Wrong,
}

impl PromptPreset {
    pub const ALL: [PromptPreset; 4] = [
        Self::SceneSpecific,
        Self::General,
        Self::Minimal,
        Self::Wrong,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Self::SceneSpecific => "Scene-specific",
            Self::General => "General",
            Self::Minimal => "Minimal",
            Self::Wrong => "Wrong",
        }
    }
    /// The pipeline's preset (same scene texts as `cgenreg register --prompt-preset`, so the
    /// GUI and the CLI share cache entries).
    pub fn pipeline(self) -> crate::wfm::PromptPreset {
        match self {
            Self::SceneSpecific => crate::wfm::PromptPreset::SceneSpecific,
            Self::General => crate::wfm::PromptPreset::General,
            Self::Minimal => crate::wfm::PromptPreset::Minimal,
            Self::Wrong => crate::wfm::PromptPreset::SemanticallyWrong,
        }
    }
    /// Scene text the preset puts in the editor: the pipeline's preset text; for
    /// scene-specific, `scene_specific` (the pair's own description) when one is known.
    pub fn scene_text(self, scene_specific: &str) -> String {
        match self {
            Self::SceneSpecific if !scene_specific.trim().is_empty() => scene_specific.to_owned(),
            p => p.pipeline().default_scene().to_owned(),
        }
    }
}

/// Which generator produces the image branch's RGB views.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum WfmChoice {
    /// Image branch off: the geometric branch alone.
    #[default]
    None,
    /// The dataset's real colour frames ("C-GenReg (Oracle)").
    Oracle,
    /// `builtin-depthshade-v1`: shading of the depth video, not a world foundation model.
    Builtin,
    /// An existing Cosmos-Transfer1 output folder plus its JSONL batch spec.
    CachedCosmos,
}

impl WfmChoice {
    pub const ALL: [WfmChoice; 4] = [Self::None, Self::Oracle, Self::Builtin, Self::CachedCosmos];
    pub fn label(self) -> &'static str {
        match self {
            Self::None => "none (geometry only)",
            Self::Oracle => "oracle (real RGB)",
            Self::Builtin => "built-in depth shading — NOT a WFM",
            Self::CachedCosmos => "cached Cosmos output (folder + spec)",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FusionMode {
    NoisyAnd,
    NoisyOr,
    Concatenation,
    ImageOnly,
    GeometryOnly,
}

impl FusionMode {
    pub const ALL: [FusionMode; 5] = [
        Self::NoisyAnd,
        Self::NoisyOr,
        Self::Concatenation,
        Self::ImageOnly,
        Self::GeometryOnly,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Self::NoisyAnd => "Noisy-AND",
            Self::NoisyOr => "Noisy-OR",
            Self::Concatenation => "Concatenation",
            Self::ImageOnly => "Image only",
            Self::GeometryOnly => "Geometry only",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Calibration {
    /// Softmax over similarities with a temperature.
    Softmax,
    /// Dual softmax (row and column).
    DualSoftmax,
    None,
}

impl Calibration {
    pub const ALL: [Calibration; 3] = [Self::Softmax, Self::DualSoftmax, Self::None];
    pub fn label(self) -> &'static str {
        match self {
            Self::Softmax => "Softmax",
            Self::DualSoftmax => "Dual softmax",
            Self::None => "None",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SelectionRule {
    MutualNearest,
    TopK,
    /// Each source point's best target, no mutual check (SC2-PCR's FPFH protocol).
    RowNearest,
}

impl SelectionRule {
    pub const ALL: [SelectionRule; 3] = [Self::MutualNearest, Self::TopK, Self::RowNearest];
    pub fn label(self) -> &'static str {
        match self {
            Self::MutualNearest => "Mutual nearest",
            Self::TopK => "Top-k by score",
            Self::RowNearest => "Best target per source",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Estimator {
    Sc2Pcr,
    Ransac,
}

impl Estimator {
    pub const ALL: [Estimator; 2] = [Self::Sc2Pcr, Self::Ransac];
    pub fn label(self) -> &'static str {
        match self {
            Self::Sc2Pcr => "SC2-PCR",
            Self::Ransac => "RANSAC",
        }
    }
}

/// Calibration of one branch.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BranchCalibration {
    pub method: Calibration,
    pub temperature: f32,
}

/// Every setting that changes a pipeline result. The worker diffs two snapshots to know
/// which stages to re-run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PipelineSettings {
    pub prompt_prefix: String,
    pub prompt_scene: String,
    pub preset: PromptPreset,
    pub k: usize,
    /// Safeguard margin m in frames: generated frames [L-m, L+m) around the source/target seam
    /// are dropped (reference §3).
    pub margin: usize,
    pub vfm: String,
    /// Generator of the image branch's views (None: geometry only).
    #[serde(default)]
    pub wfm: WfmChoice,
    /// Cosmos output folder and JSONL spec for [`WfmChoice::CachedCosmos`].
    #[serde(default)]
    pub wfm_dir: String,
    #[serde(default)]
    pub wfm_spec: String,
    /// Generation seed.
    #[serde(default)]
    pub seed: u64,
    /// XFeat ONNX file; empty = the default `models/xfeat.onnx`.
    #[serde(default)]
    pub vfm_model: String,
    pub image_calibration: BranchCalibration,
    pub geometry_calibration: BranchCalibration,
    pub fusion: FusionMode,
    pub selection: SelectionRule,
    pub estimator: Estimator,
}

impl Default for PipelineSettings {
    fn default() -> Self {
        Self {
            prompt_prefix: crate::wfm::prompt::DEFAULT_PREFIX.into(),
            prompt_scene: PromptPreset::SceneSpecific.scene_text(""),
            preset: PromptPreset::SceneSpecific,
            k: 4,
            margin: 3,
            vfm: "xfeat".into(),
            wfm: WfmChoice::None,
            wfm_dir: String::new(),
            wfm_spec: String::new(),
            seed: 0,
            vfm_model: String::new(),
            image_calibration: BranchCalibration {
                method: Calibration::Softmax,
                temperature: 0.1,
            },
            geometry_calibration: BranchCalibration {
                method: Calibration::Softmax,
                temperature: 0.1,
            },
            fusion: FusionMode::NoisyAnd,
            selection: SelectionRule::MutualNearest,
            estimator: Estimator::Sc2Pcr,
        }
    }
}

impl PipelineSettings {
    /// The full prompt sent to the generator (as `crate::wfm::Prompt::text`).
    pub fn prompt(&self) -> String {
        self.wfm_prompt().text()
    }
    pub fn wfm_prompt(&self) -> crate::wfm::Prompt {
        crate::wfm::Prompt::new(self.prompt_prefix.trim(), self.prompt_scene.trim())
    }
}

/// What a dropped or chosen path is meant to be.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OpenKind {
    /// Decide from the file names (drag and drop).
    Auto,
    Manifest,
    ThreeDMatchFolder,
    RgbdSequence,
    /// Exactly two cloud files: source then target.
    TwoClouds,
    CosmosOutput,
}

impl OpenKind {
    pub fn label(self) -> &'static str {
        match self {
            Self::Auto => "Auto",
            Self::Manifest => "Dataset manifest…",
            Self::ThreeDMatchFolder => "3DMatch folder…",
            Self::RgbdSequence => "RGB-D sequence…",
            Self::TwoClouds => "Two cloud files…",
            Self::CosmosOutput => "Cosmos output folder…",
        }
    }
    pub fn wants_folder(self) -> bool {
        matches!(
            self,
            Self::ThreeDMatchFolder | Self::RgbdSequence | Self::CosmosOutput
        )
    }
}

/// A request from the UI to the worker.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    Open {
        kind: OpenKind,
        paths: Vec<PathBuf>,
    },
    SelectPair(String),
    /// New settings snapshot; re-run the stages that depend on what changed, from the cache.
    ApplySettings(PipelineSettings),
    /// Run the configured generator for a prompt whose generation is not cached.
    RunGenerator {
        prompt: String,
    },
    /// Compute branch posteriors for a source point (posterior inspector).
    InspectSourcePoint(usize),
    /// Run a parameter study over the open dataset's pairs with the current settings.
    RunStudy(StudyRequest),
    /// Precision-recall of Noisy-AND and Noisy-OR for the current pair (figure 7), sent by
    /// the plots panel while it is shown, so other tabs never pay for the two extra fusions.
    Figure7,
    /// Open data (the last opened, at start); if that fails, log why and register
    /// `fallback_pair` of the dataset already loaded (the bundled demo).
    OpenOrFallback {
        kind: OpenKind,
        paths: Vec<PathBuf>,
        fallback_pair: String,
    },
    Cancel,
}

/// Which study the plots panel asked for.
#[derive(Clone, Debug, PartialEq)]
pub enum StudyRequest {
    /// RRE/RTE against K (figure 6) for these K values.
    K(Vec<usize>),
    /// RRE/RTE per prompt category (figure 4): the four presets with the editor's prefix,
    /// plus the editor's scene description as "custom" when it is none of the presets.
    Prompt,
}

impl Command {
    /// Commands of the same kind supersede each other when queued (slider drags).
    fn coalesces_with(&self, other: &Command) -> bool {
        matches!(
            (self, other),
            (Command::ApplySettings(_), Command::ApplySettings(_))
                | (
                    Command::InspectSourcePoint(_),
                    Command::InspectSourcePoint(_)
                )
                | (Command::SelectPair(_), Command::SelectPair(_))
                | (Command::Figure7, Command::Figure7)
        )
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogLevel {
    Info,
    Warn,
    Error,
}

/// What the worker reports back.
#[derive(Clone, Debug)]
pub enum WorkerEvent {
    /// A new model replaces the shown one.
    Model(Box<InspectorModel>),
    /// One stage changed state (the stage panel updates without a full model).
    Stage(StageInfo),
    /// A long task's progress: (what, done, total).
    Progress(String, usize, usize),
    /// The worker changed the settings (e.g. opening a Cosmos output folder switched the image
    /// branch): the controls show these from now on.
    Settings(Box<PipelineSettings>),
    Log(LogLevel, String),
}

/// Sends events to the UI and wakes it up.
#[derive(Clone)]
pub struct EventSink {
    tx: Sender<WorkerEvent>,
    ctx: Option<egui::Context>,
}

impl EventSink {
    pub fn send(&self, event: WorkerEvent) {
        // A closed UI is not an error for the worker.
        let _ = self.tx.send(event);
        if let Some(ctx) = &self.ctx {
            ctx.request_repaint();
        }
    }
    pub fn log(&self, level: LogLevel, msg: impl Into<String>) {
        self.send(WorkerEvent::Log(level, msg.into()));
    }
}

/// The pipeline side of the inspector; runs on its own thread.
pub trait Worker: Send + 'static {
    /// Handle one command. Long work is fine here (it never blocks the UI); report progress
    /// and results through `events`. Errors must be reported as `WorkerEvent::Log(Error, ..)`
    /// and stage `Failed` states, never by panicking.
    fn handle(&mut self, command: Command, events: &EventSink);
    /// The flag [`WorkerHandle::send`] raises on [`Command::Cancel`], read by long work
    /// (studies) while the worker thread is busy. Default: nothing to cancel.
    fn cancel_flag(&self) -> Option<std::sync::Arc<std::sync::atomic::AtomicBool>> {
        None
    }
}

/// A worker that only logs what it receives (for a UI without a pipeline).
pub struct LogOnlyWorker;

impl Worker for LogOnlyWorker {
    fn handle(&mut self, command: Command, events: &EventSink) {
        events.log(
            LogLevel::Info,
            format!("no pipeline connected; ignored {command:?}"),
        );
    }
}

/// The UI's end of the worker channel.
pub struct WorkerHandle {
    tx: Sender<Command>,
    rx: Receiver<WorkerEvent>,
    cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    _thread: Option<std::thread::JoinHandle<()>>,
}

impl WorkerHandle {
    /// Queues `command`. A Cancel also raises the worker's cancel flag at once, since a busy
    /// worker reads the queue only when its current task ends.
    pub fn send(&self, command: Command) -> bool {
        if command == Command::Cancel {
            if let Some(c) = &self.cancel {
                c.store(true, std::sync::atomic::Ordering::Relaxed);
            }
        }
        self.tx.send(command).is_ok()
    }
    /// Drains pending events without blocking.
    pub fn poll(&self) -> Vec<WorkerEvent> {
        let mut out = Vec::new();
        loop {
            match self.rx.try_recv() {
                Ok(e) => out.push(e),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    out.push(WorkerEvent::Log(
                        LogLevel::Error,
                        "worker thread ended".into(),
                    ));
                    break;
                }
            }
        }
        out
    }
}

/// Starts `worker` on a thread. Queued commands of the same kind are coalesced so a slider
/// drag re-runs once with the last value. A panicking worker is reported, not propagated.
pub fn spawn_worker(mut worker: Box<dyn Worker>, ctx: Option<egui::Context>) -> WorkerHandle {
    let (tx, cmd_rx) = channel::<Command>();
    let (ev_tx, rx) = channel::<WorkerEvent>();
    let sink = EventSink { tx: ev_tx, ctx };
    let cancel = worker.cancel_flag();
    let thread = std::thread::Builder::new()
        .name("cgenreg-worker".into())
        .spawn(move || {
            while let Ok(first) = cmd_rx.recv() {
                let mut batch = vec![first];
                while let Ok(c) = cmd_rx.try_recv() {
                    batch.retain(|b| !b.coalesces_with(&c));
                    batch.push(c);
                }
                for c in batch {
                    let desc = format!("{c:?}");
                    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        worker.handle(c, &sink)
                    }));
                    if r.is_err() {
                        sink.log(
                            LogLevel::Error,
                            format!("worker panicked while handling {desc}"),
                        );
                    }
                }
            }
        })
        .ok();
    WorkerHandle {
        tx,
        rx,
        cancel,
        _thread: thread,
    }
}

/// The side-panel controls. Returns the commands the user's changes produced.
pub fn controls_ui(
    ui: &mut egui::Ui,
    settings: &mut PipelineSettings,
    scene_specific: &str,
    out: &mut Vec<Command>,
) {
    let before = settings.clone();
    egui::CollapsingHeader::new("Prompt")
        .default_open(true)
        .show(ui, |ui| {
            ui.horizontal_wrapped(|ui| {
                for p in PromptPreset::ALL {
                    if ui
                        .selectable_label(settings.preset == p, p.label())
                        .clicked()
                    {
                        settings.preset = p;
                        settings.prompt_scene = p.scene_text(scene_specific);
                    }
                }
            });
            let l = ui.label("Shared prefix");
            ui.add(
                egui::TextEdit::multiline(&mut settings.prompt_prefix)
                    .desired_rows(2)
                    .desired_width(f32::INFINITY),
            )
            .labelled_by(l.id);
            let l = ui.label("Scene description");
            ui.add(
                egui::TextEdit::multiline(&mut settings.prompt_scene)
                    .desired_rows(3)
                    .desired_width(f32::INFINITY),
            )
            .labelled_by(l.id);
        });
    egui::CollapsingHeader::new("Image branch")
        .default_open(true)
        .show(ui, |ui| {
            egui::ComboBox::from_label("WFM")
                .selected_text(settings.wfm.label())
                .width(220.0)
                .show_ui(ui, |ui| {
                    for w in WfmChoice::ALL {
                        ui.selectable_value(&mut settings.wfm, w, w.label());
                    }
                });
            if settings.wfm == WfmChoice::CachedCosmos {
                path_field(ui, "Cosmos output folder", &mut settings.wfm_dir);
                path_field(ui, "JSONL spec", &mut settings.wfm_spec);
            }
            ui.horizontal(|ui| {
                let l = ui.label("Seed");
                ui.add(egui::DragValue::new(&mut settings.seed))
                    .labelled_by(l.id);
            });
        });
    egui::CollapsingHeader::new("Views")
        .default_open(true)
        .show(ui, |ui| {
            ui.add(egui::Slider::new(&mut settings.k, 1..=8).text("K views"));
            ui.add(
                egui::Slider::new(&mut settings.margin, 0..=10).text("Safeguard margin (frames)"),
            );
            egui::ComboBox::from_label("VFM")
                .selected_text(settings.vfm.clone())
                .show_ui(ui, |ui| {
                    // MASt3R needs the user's own export in the model field below
                    ui.selectable_value(&mut settings.vfm, "xfeat".to_owned(), "xfeat");
                    ui.selectable_value(
                        &mut settings.vfm,
                        "mast3r".to_owned(),
                        "mast3r (your ONNX export)",
                    );
                });
            path_field(ui, "XFeat model (empty: default)", &mut settings.vfm_model);
        });
    egui::CollapsingHeader::new("Calibration & fusion")
        .default_open(true)
        .show(ui, |ui| {
            for (name, cal) in [
                ("Image", &mut settings.image_calibration),
                ("Geometry", &mut settings.geometry_calibration),
            ] {
                ui.horizontal(|ui| {
                    egui::ComboBox::from_label(format!("{name} calibration"))
                        .selected_text(cal.method.label())
                        .show_ui(ui, |ui| {
                            for c in Calibration::ALL {
                                ui.selectable_value(&mut cal.method, c, c.label());
                            }
                        });
                });
                ui.add(
                    egui::Slider::new(&mut cal.temperature, 0.005..=1.0)
                        .logarithmic(true)
                        .text(format!("{name} temperature")),
                );
            }
            egui::ComboBox::from_label("Fusion")
                .selected_text(settings.fusion.label())
                .show_ui(ui, |ui| {
                    for f in FusionMode::ALL {
                        ui.selectable_value(&mut settings.fusion, f, f.label());
                    }
                });
            egui::ComboBox::from_label("Selection")
                .selected_text(settings.selection.label())
                .show_ui(ui, |ui| {
                    for s in SelectionRule::ALL {
                        ui.selectable_value(&mut settings.selection, s, s.label());
                    }
                });
            egui::ComboBox::from_label("Estimator")
                .selected_text(settings.estimator.label())
                .show_ui(ui, |ui| {
                    for e in Estimator::ALL {
                        ui.selectable_value(&mut settings.estimator, e, e.label());
                    }
                });
        });
    if *settings != before {
        out.push(Command::ApplySettings(settings.clone()));
    }
}

/// A path text field that commits on Enter or when it loses focus (not per keystroke, so a
/// half-typed path never re-runs the pipeline).
fn path_field(ui: &mut egui::Ui, label: &str, value: &mut String) {
    let id = ui.make_persistent_id(("path_field", label));
    let mut buf: String = ui
        .data_mut(|d| d.get_temp::<String>(id))
        .unwrap_or_else(|| value.clone());
    let l = ui.label(label);
    let r = ui
        .add(egui::TextEdit::singleline(&mut buf).desired_width(f32::INFINITY))
        .labelled_by(l.id);
    if r.lost_focus() || (r.has_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter))) {
        *value = buf.trim().to_owned();
        ui.data_mut(|d| d.remove::<String>(id));
    } else if r.has_focus() {
        ui.data_mut(|d| d.insert_temp(id, buf));
    } else {
        ui.data_mut(|d| d.remove::<String>(id));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    struct Recorder(Arc<Mutex<Vec<Command>>>);
    impl Worker for Recorder {
        fn handle(&mut self, command: Command, events: &EventSink) {
            std::thread::sleep(std::time::Duration::from_millis(20));
            self.0.lock().unwrap().push(command.clone());
            events.log(LogLevel::Info, format!("{command:?}"));
        }
    }

    #[test]
    fn worker_coalesces_settings_and_reports() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let h = spawn_worker(Box::new(Recorder(seen.clone())), None);
        // first command is taken at once; the next ones queue while it sleeps
        h.send(Command::Cancel);
        std::thread::sleep(std::time::Duration::from_millis(5));
        for k in 1..=5 {
            h.send(Command::ApplySettings(PipelineSettings {
                k,
                ..Default::default()
            }));
        }
        h.send(Command::RunGenerator { prompt: "p".into() });
        let t0 = std::time::Instant::now();
        while seen.lock().unwrap().len() < 3 && t0.elapsed().as_secs() < 5 {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
        let seen = seen.lock().unwrap().clone();
        assert_eq!(seen[0], Command::Cancel);
        let applied: Vec<usize> = seen
            .iter()
            .filter_map(|c| match c {
                Command::ApplySettings(s) => Some(s.k),
                _ => None,
            })
            .collect();
        assert_eq!(
            applied,
            vec![5],
            "only the last settings snapshot runs: {seen:?}"
        );
        assert!(seen.contains(&Command::RunGenerator { prompt: "p".into() }));
        let logs = h.poll();
        assert_eq!(logs.len(), seen.len());
    }

    #[test]
    fn prompt_joins_prefix_and_scene() {
        let mut s = PipelineSettings {
            prompt_scene: PromptPreset::Minimal.scene_text("x"),
            prompt_prefix: "A photorealistic".into(),
            ..Default::default()
        };
        assert_eq!(s.prompt(), "A photorealistic an indoor scene");
        s.prompt_prefix.clear();
        assert_eq!(s.prompt(), "an indoor scene");
        // the default prompt is the CLI's default (shared cache entries)
        assert_eq!(
            PipelineSettings::default().prompt(),
            crate::wfm::Prompt::from_preset(crate::wfm::PromptPreset::SceneSpecific).text()
        );
    }
}
