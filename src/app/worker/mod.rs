//! The inspector's pipeline worker: owns a dataset, registers the selected pair with the UI's
//! settings on the worker thread (the image branch through the stage cache when a WFM is
//! chosen), and turns the result into an [`InspectorModel`].
//!
//! What is kept in memory per pair: the geometric branch (keypoints + FPFH) and, after a run
//! with the image branch, every input of the in-memory stages ([`FusionInputs`]) and the
//! selected views. A change of temperature, calibration, fusion mode, selection or estimator
//! then re-runs only similarity, fusion and estimation
//! ([`crate::pipeline::Registration::refuse_from_memory`]); a change of
//! prompt, seed, K, margin, VFM or backend re-runs the cached pipeline.
//!
//! Model conventions: `model.source` / `model.target` start with the registration keypoints
//! (so `MatchInfo::src` / `tgt` are keypoint indices), followed by a strided subsample of the
//! full scan for display. Clouds stay in their own scan frames; `estimated` and
//! `ground_truth` are target_from_source.
//!
//! Files: this one holds the worker's state and its command dispatch ([`Worker::handle`]);
//! `session.rs` registers one pair and answers re-fusions and posterior requests,
//! `model_build.rs` turns a result into the model, `study.rs` runs K / prompt studies,
//! `open.rs` opens datasets and Cosmos output folders.

mod compare_run;
mod inspect;
mod model_build;
mod open;
mod preview;
mod run_all;
mod session;
mod study;

use std::sync::Arc;
use std::time::Instant;

use super::channel::{Command, EventSink, LogLevel, Worker, WorkerEvent};
use super::model::StageRole;
use super::model::{InspectorModel, PairEntry, PairStatus, StageInfo, StageState};
use crate::cache::Cache;
use crate::dataset::manifest::Dataset;
use crate::dataset::ScanPair;
use crate::fusion::fuse::FusionMode;
use crate::pipeline::memo::{Lru, Memo};
use crate::pipeline::plan::{Plan, StageName};
use crate::pipeline::tail::{FusionInputs, Similarities};
use crate::pipeline::{ImageBranchOutput, RegisterParams, RegistrationResult};

pub use model_build::{
    default_posterior_point, point_posterior, pr_curve, result_to_model, ViewMemo, DISPLAY_POINTS,
    FIGURE7_CORRECT_M, IMAGE_BRANCH_OFF, VIEW_MEMO,
};
pub use run_all::RunAllSummary;
use study::StudyPlots;

/// Loaded pairs the worker keeps (a real 3DMatch pair is a few hundred thousand points).
pub const LOADED_PAIRS: usize = 8;
/// Geometric branches the worker keeps (per pair and voxel size).
pub const GEO_BRANCHES: usize = 8;

/// What a run left in memory for fast re-runs of the stages after it.
struct Kept {
    /// The plan of the run that produced `inputs`, its keys filled by the run (then by each
    /// re-fusion's settings): a settings change re-uses `inputs` only when it changes no key
    /// but the fusion stage's (None: any change re-runs through the cache).
    plan: Option<Plan>,
    inputs: Arc<FusionInputs>,
    /// Both similarity matrices (about 2 x 200 MB at 7k keypoints, for the current pair only):
    /// a temperature change then costs fusion + estimate only.
    sims: Option<Arc<Similarities>>,
    /// The last re-fusion's estimate and its inputs (skipped when they repeat).
    estimates: crate::pipeline::tail::EstimateMemo,
    image: Option<ImageBranchOutput>,
    /// Stages of that run (shown as cached when only fusion onward re-runs).
    stages: Vec<StageInfo>,
    note: Option<String>,
    generation_missing: Option<String>,
}

/// A pair loaded and registered, kept for re-runs and posterior requests.
struct Current {
    pair: ScanPair,
    result: RegistrationResult,
    model: InspectorModel,
    kept: Option<Kept>,
}

/// The stage-panel row naming what a settings change invalidated, earliest stage first, and
/// how long comparing the keys took.
fn invalidated_row(stages: &[StageName], ms: f64) -> StageInfo {
    let name = match stages {
        [] => "settings change: no stage key changed".to_string(),
        [only] => format!("settings change invalidated: {}", only.label()),
        [first, rest @ ..] => format!(
            "settings change invalidated: {} and {} later stage{}",
            first.label(),
            rest.len(),
            if rest.len() == 1 { "" } else { "s" }
        ),
    };
    StageInfo {
        name,
        stage: None,
        state: StageState::Done,
        time_ms: Some(ms),
        role: StageRole::Stage,
    }
}

/// The [`Worker`] behind `cgenreg inspect`.
pub struct PipelineWorker {
    dataset: Dataset,
    /// The parameters in force: the command line's at start, then the controls'.
    params: RegisterParams,
    pairs: Vec<PairEntry>,
    current: Option<Current>,
    /// Loaded pairs by id (loading a fragment is the slowest step for real scans); the
    /// [`LOADED_PAIRS`] most recently used.
    loaded: Lru<String, ScanPair>,
    /// Geometric branch by the two scans' `geo-fpfh` stage keys, so geometry-only re-runs
    /// skip FPFH; the [`GEO_BRANCHES`] most recently used.
    geo: Lru<String, Arc<FusionInputs>>,
    /// File hashes and loaded VFM models, for every registration this worker runs.
    memo: Memo,
    /// The views' depth frames and visibility, for re-fusions that show the same views.
    views: ViewMemo,
    /// The stage cache of the image branch (None: everything computed in memory).
    cache: Option<Arc<Cache>>,
    /// Why there is no cache, reported once.
    cache_note: Option<String>,
    /// Results of the last K sweep / prompt study on this dataset (kept in every model).
    studies: StudyPlots,
    /// Set by the UI thread (WorkerHandle::send(Command::Cancel)) to stop a running study
    /// between pairs; the worker is busy then and reads no commands.
    cancel: Arc<std::sync::atomic::AtomicBool>,
    /// The stage-panel row of the last settings change that needs a run (shown by that run).
    invalidated: Option<StageInfo>,
    /// While the bundled demo is open under its own protocol ([`demo_protocol`]): the user's
    /// settings it replaced, restored when other data is opened.
    demo_user: Option<RegisterParams>,
    /// The pair last asked for, kept when its run fails (an error row): the generator, a
    /// geometry-only run and every settings change still run it.
    selected: Option<String>,
    /// The pair whose preview is shown and whose settings' own result is still to compute
    /// (when no command is queued: [`Worker::idle`]).
    refine: Option<String>,
}

/// The bundled demo's protocol: its sequences have 8 frames, so L = 8, m = 1 and K = 2 views
/// per side, shaded by the built-in generator (NOT a WFM). A property of that dataset, not a
/// setting: it applies while the demo is open and never to other data.
pub fn demo_protocol(user: &RegisterParams) -> RegisterParams {
    let mut p = user.clone();
    let mut ib = user.image.clone().unwrap_or_default();
    ib.backend = crate::pipeline::WfmSpec::Builtin;
    (ib.frames_per_fragment, ib.margin, ib.k) = (8, 1, 2);
    if user.image.is_none() {
        // the paper's fusion (Noisy-AND of mutual nearest neighbours): the demo shows the
        // method as published, not the default `visibility` rule of `register --wfm`
        p.fusion.mode = crate::fusion::FusionMode::NoisyAnd;
        p.fusion.selection = crate::fusion::Selection::MutualNn;
    }
    p.image = Some(ib);
    p
}

/// The user's own settings after `new` was applied while the demo's protocol is in force:
/// a field the protocol sets (image branch, fusion mode, selection) is the user's choice only
/// when it differs from the protocol's value; every other field is taken as set.
fn user_settings_under_demo(user: &RegisterParams, new: &RegisterParams) -> RegisterParams {
    let demo = demo_protocol(user);
    let mut u = new.clone();
    if new.image == demo.image {
        u.image = user.image.clone();
    }
    if new.fusion.mode == demo.fusion.mode {
        u.fusion.mode = user.fusion.mode;
    }
    if new.fusion.selection == demo.fusion.selection {
        u.fusion.selection = user.fusion.selection;
    }
    u
}

/// What the demo protocol says of itself (the controls and the status area show it).
pub const DEMO_PROTOCOL_NOTE: &str = "Demo protocol: built-in frames (NOT a WFM), L = 8, m = 1, \
     K = 2. It belongs to the bundled demo: opening other data restores your settings, and it \
     is never saved.";

impl PipelineWorker {
    /// A worker on `dataset` with the default stage cache (`$CGENREG_CACHE` or
    /// `~/.cache/cgenreg`).
    pub fn new(dataset: Dataset, base: RegisterParams) -> Self {
        let dir = crate::cache::default_cache_dir();
        let (cache, cache_note) = match Cache::open(&dir) {
            Ok(c) => (Some(Arc::new(c)), None),
            Err(e) => (
                None,
                Some(format!(
                    "stage cache {} unavailable ({e}); the image branch computes every stage in memory",
                    dir.display()
                )),
            ),
        };
        Self::with_cache(dataset, base, cache, cache_note)
    }

    pub(super) fn with_cache(
        dataset: Dataset,
        base: RegisterParams,
        cache: Option<Arc<Cache>>,
        cache_note: Option<String>,
    ) -> Self {
        let pairs = dataset.pairs().iter().map(PairEntry::of_spec).collect();
        let mut params = base;
        if params.image.is_none() {
            // without the image branch only geometry-only fusion runs: show what ran
            params.fusion.mode = FusionMode::default_for(false, false);
        }
        Self {
            dataset,
            params,
            pairs,
            current: None,
            loaded: Lru::new(LOADED_PAIRS),
            geo: Lru::new(GEO_BRANCHES),
            memo: Memo::default(),
            views: ViewMemo::new(VIEW_MEMO),
            cache,
            cache_note,
            studies: StudyPlots::default(),
            cancel: Arc::default(),
            invalidated: None,
            demo_user: None,
            selected: None,
            refine: None,
        }
    }

    /// Replaces the stage cache (None: compute every stage in memory, `--no-cache`).
    pub fn set_cache(&mut self, cache: Option<Cache>) {
        self.cache_note = None;
        self.cache = cache.map(Arc::new);
    }

    /// Opens a manifest file.
    pub fn open_manifest(path: &std::path::Path, base: RegisterParams) -> crate::Result<Self> {
        Ok(Self::new(Dataset::load(path)?, base))
    }

    pub fn pair_ids(&self) -> Vec<String> {
        self.pairs.iter().map(|p| p.id.clone()).collect()
    }

    /// The model shown before the first result: the pair list and pending stages.
    pub fn initial_model(&self, pair: Option<&str>) -> InspectorModel {
        let mut pairs = self.pairs.clone();
        let current = pair.and_then(|id| pairs.iter().position(|p| p.id == id));
        if let Some(i) = current {
            pairs[i].status = PairStatus::Running;
        }
        InspectorModel {
            pairs,
            current_pair: current,
            scene_prompt: self.dataset.scene_prompt.clone(),
            stages: vec![StageInfo {
                name: "load + register".into(),
                stage: None,
                state: StageState::Running,
                time_ms: None,
                role: StageRole::Container,
            }],
            image_branch_note: Some(if self.params.image.is_some() {
                "registering…".to_string()
            } else {
                IMAGE_BRANCH_OFF.to_string()
            }),
            ..Default::default()
        }
    }

    /// Records a pair that could not be registered (shown as failed in the browser).
    pub fn mark_failed(&mut self, id: &str, why: &str) {
        if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
            p.status = PairStatus::Failed(why.to_string());
        }
    }

    /// The parameters in force (what the controls show).
    pub fn params(&self) -> &RegisterParams {
        &self.params
    }

    /// Replaces the parameters without running anything (the next run uses them).
    pub fn set_params(&mut self, p: RegisterParams) {
        self.params = p;
    }

    /// The current pair's registration result (what the inspector shows).
    pub fn result(&self) -> Option<&RegistrationResult> {
        self.current.as_ref().map(|c| &c.result)
    }

    /// Runs the open dataset (the bundled demo) under [`demo_protocol`]; the settings in
    /// force until now come back when other data is opened.
    pub fn enter_demo_protocol(&mut self) {
        let user = self.demo_user.take().unwrap_or_else(|| self.params.clone());
        self.params = demo_protocol(&user);
        self.demo_user = Some(user);
    }

    /// The pair shown: the one registered, else the one last asked for (its run failed).
    pub fn selected_pair(&self) -> Option<String> {
        self.current
            .as_ref()
            .map(|c| c.result.pair_id.clone())
            .or_else(|| self.selected.clone())
    }

    /// Pair `id` under the protocol its manifest names, when that differs from the previous
    /// pair's (a pair with its own `preset`): resolved as `register` resolves it, saying so.
    fn follow_pair_preset(&mut self, id: &str, events: &EventSink) {
        let prev = self.selected_pair();
        let (now, before) = (
            self.dataset.preset_of(id),
            prev.as_deref().and_then(|p| self.dataset.preset_of(p)),
        );
        if prev.is_none() || now == before {
            return;
        }
        let ms = crate::pipeline::manifest_settings::ManifestSettings::of_pair(&self.dataset, id);
        let what = format!("pair {id}");
        if let Some(n) =
            crate::pipeline::manifest_settings::adopt_preset(&mut self.params, &what, &ms)
        {
            events.log(LogLevel::Warn, n);
            events.send(WorkerEvent::Settings(Box::new(self.params.clone())));
        }
    }

    /// Whether the demo's protocol is in force.
    pub fn demo_protocol_active(&self) -> bool {
        self.demo_user.is_some()
    }

    /// The settings that other data gets: the user's (the demo's protocol taken out).
    pub fn user_params(&self) -> &RegisterParams {
        self.demo_user.as_ref().unwrap_or(&self.params)
    }
}

impl Worker for PipelineWorker {
    fn cancel_flag(&self) -> Option<Arc<std::sync::atomic::AtomicBool>> {
        Some(self.cancel.clone())
    }

    fn idle(&mut self, events: &EventSink) -> bool {
        self.refine(events)
    }

    fn handle(&mut self, command: Command, events: &EventSink) {
        // a preview's refinement: dropped by what replaces it (new settings, another pair or
        // data), finished before anything that reads the result
        match &command {
            Command::ApplySettings(_)
            | Command::SelectPair(_)
            | Command::OpenPairWith { .. }
            | Command::Open { .. }
            | Command::OpenOrFallback { .. } => self.refine = None,
            Command::Cancel => {}
            _ => {
                self.refine(events);
            }
        }
        match command {
            Command::SelectPair(id) => {
                self.follow_pair_preset(&id, events);
                self.run_and_report(&id, true, events)
            }
            Command::OpenPairWith { pair, params } => {
                self.params = params;
                self.run_and_report(&pair, true, events);
            }
            Command::Figure7 => self.send_figure7(events),
            Command::ApplySettings(s) => {
                // a new prompt or seed is not generated without asking (the button)
                let gen_of = |p: &RegisterParams| p.image.as_ref().map(|i| (i.prompt.text(), i.seed));
                let generate = gen_of(&s) == gen_of(&self.params);
                if let Some(user) = self.demo_user.as_mut() {
                    *user = user_settings_under_demo(user, &s);
                }
                self.params = s;
                let Some(id) = self.selected_pair() else {
                    events.log(LogLevel::Info, "settings stored; no pair selected yet");
                    return;
                };
                // under the visibility rule: the fast answer first, refined when idle
                if self.send_preview(&id, events) {
                    return;
                }
                let t = Instant::now();
                match self.refuse_from_memory() {
                    Some(r) => self.report(&id, t, r, "re-fuse from memory", events),
                    None => self.run_and_report(&id, generate, events),
                }
            }
            Command::RunStudy(req) => self.study(req, events),
            Command::RunAll(sel) => self.run_all_and_report(sel, events),
            Command::CompareSettings(req) => self.compare_settings_and_report(*req, events),
            Command::InspectSourcePoint(i) => match self.inspect_point(i) {
                Ok(m) => events.send(WorkerEvent::Model(Box::new(m))),
                Err(e) => events.log(LogLevel::Warn, format!("posterior of point {i}: {e}")),
            },
            Command::Open { kind, paths } => {
                self.open(kind, paths, events);
            }
            Command::OpenOrFallback {
                kind,
                paths,
                fallback_pair,
            } => {
                events.log(
                    LogLevel::Info,
                    format!("reopening the last opened data: {paths:?}"),
                );
                if !self.open(kind, paths, events) {
                    events.log(
                        LogLevel::Error,
                        format!("could not reopen the last opened data; showing {fallback_pair}"),
                    );
                    self.run_and_report(&fallback_pair, true, events);
                }
            }
            Command::RunGenerator { prompt } => {
                let Some(ib) = &self.params.image else {
                    events.log(
                        LogLevel::Warn,
                        "no generator configured: choose a WFM under “Image branch”",
                    );
                    return;
                };
                let backend = ib.backend.label();
                if prompt.trim() != ib.prompt.text().trim() {
                    events.log(
                        LogLevel::Warn,
                        "the prompt changed since the request; generating for the prompt in the editor",
                    );
                }
                match self.selected_pair() {
                    Some(id) => {
                        events.log(
                            LogLevel::Info,
                            format!("{id}: running the generator ({backend})"),
                        );
                        self.run_and_report(&id, true, events)
                    }
                    None => events.log(LogLevel::Warn, "select a pair first"),
                }
            }
            Command::ExportCorrespondences(path) => match self.export_correspondences(&path) {
                Ok(n) => events.log(
                    LogLevel::Info,
                    format!("wrote {n} correspondences to {}", path.display()),
                ),
                Err(e) => events.log(LogLevel::Error, format!("export correspondences: {e}")),
            },
            Command::Hypotheses => match self.hypotheses() {
                Ok(m) => events.send(WorkerEvent::Model(Box::new(m))),
                Err(e) => events.log(LogLevel::Warn, format!("hypotheses: {e}")),
            },
            Command::Cancel => events.log(
                LogLevel::Info,
                "cancel: a running study or run-all stops before its next pair; registrations run to completion",
            ),
        }
    }
}
