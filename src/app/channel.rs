//! The channel between the UI and the worker thread that runs the pipeline: the UI's
//! [`Command`]s, the worker's [`WorkerEvent`]s, the [`Worker`] trait the pipeline side
//! implements ([`crate::app::worker::PipelineWorker`]) and the UI's [`WorkerHandle`]
//! ([`spawn_worker`] starts the thread). Plain `std::sync::mpsc`; it knows the model and
//! nothing of the panels.

use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};

use eframe::egui;

use super::model::{CompareEvent, InspectorModel, PairEntry, SettingsCompareRequest, StageInfo};
use crate::pipeline::params::RegisterParams;

pub use crate::dataset::open::OpenKind;

/// A request from the UI to the worker.
// ApplySettings carries the whole parameter set; commands are few per frame, so the size
// difference costs nothing worth a Box at every call site.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    Open {
        kind: OpenKind,
        paths: Vec<PathBuf>,
    },
    SelectPair(String),
    /// Register `pair` with `params` (another run's settings, from the Compare tab): the
    /// settings change and the pair is selected in one step, so the current pair is not
    /// re-run with the new settings first.
    OpenPairWith {
        pair: String,
        params: RegisterParams,
    },
    /// New parameters; re-run the stages that depend on what changed, from the cache.
    ApplySettings(RegisterParams),
    /// Run the configured generator for a prompt whose generation is not cached.
    RunGenerator {
        prompt: String,
    },
    /// Compute branch posteriors for a source point (posterior inspector).
    InspectSourcePoint(usize),
    /// Run a parameter study over the open dataset's pairs with the current settings.
    RunStudy(StudyRequest),
    /// Register the pairs `RunSelection` picks with the current settings (through the stage
    /// cache), filling the pair browser; Cancel stops it between pairs.
    RunAll(RunSelection),
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
    /// Write the current pair's selected correspondences to an `.npz`
    /// ([`crate::pipeline::export`], the same as `register --export-corr`).
    ExportCorrespondences(PathBuf),
    /// The estimator's ranked hypotheses for the current pair (the hypothesis browser, sent
    /// while it is shown and the model has none).
    Hypotheses,
    /// Register the open dataset's pairs with two settings and send both runs back (the
    /// Compare tab's "Run A vs B"); Cancel stops it between registrations.
    CompareSettings(Box<SettingsCompareRequest>),
    Cancel,
}

/// Which pairs "Run all" registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunSelection {
    /// Every pair of the dataset.
    All,
    /// Pairs not run yet, in error, or registered outside the success thresholds.
    FailedOrPending,
}

/// One step of a "Run all": before a pair runs (`row` None), after it (its new row), and at
/// the end (`finished`).
#[derive(Clone, Debug, PartialEq)]
pub struct RunProgress {
    /// Pairs finished so far.
    pub done: usize,
    pub total: usize,
    /// The pair starting or just finished.
    pub pair: String,
    pub row: Option<PairEntry>,
    pub finished: bool,
    /// The run ended by Cancel before its last pair.
    pub cancelled: bool,
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
                | (Command::OpenPairWith { .. }, Command::OpenPairWith { .. })
                | (Command::Figure7, Command::Figure7)
                | (Command::Hypotheses, Command::Hypotheses)
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
// A run's progress (one row, a few hundred bytes) is sent twice per pair: a move of that size
// costs less than boxing it; the model, megabytes, is boxed.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum WorkerEvent {
    /// A new model replaces the shown one.
    Model(Box<InspectorModel>),
    /// One stage changed state (the stage panel updates without a full model).
    Stage(StageInfo),
    /// "Run all" progress: a row of the pair browser changed.
    RunAll(RunProgress),
    /// A long task's progress: (what, done, total).
    Progress(String, usize, usize),
    /// The worker changed the settings (e.g. opening a Cosmos output folder switched the image
    /// branch): the controls show these from now on.
    Settings(Box<RegisterParams>),
    /// A settings comparison's progress, or its two runs.
    Compare(CompareEvent),
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
    /// Work left for when no command is queued (refining a preview the last command showed):
    /// one step per call; false when there was none. A queued command goes first, so a slider
    /// drag shows a preview per value and refines the last one only.
    fn idle(&mut self, _events: &EventSink) -> bool {
        false
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
        .spawn(move || loop {
            let first = match cmd_rx.try_recv() {
                Ok(c) => c,
                Err(TryRecvError::Disconnected) => break,
                Err(TryRecvError::Empty) => {
                    let mut did = false;
                    let r = crate::error::catch_panic(|| {
                        did = worker.idle(&sink);
                        Ok(())
                    });
                    if let Err(e) = r {
                        sink.log(LogLevel::Error, format!("worker {e} (while refining)"));
                    }
                    if did {
                        continue;
                    }
                    match cmd_rx.recv() {
                        Ok(c) => c,
                        Err(_) => break,
                    }
                }
            };
            let mut batch = vec![first];
            while let Ok(c) = cmd_rx.try_recv() {
                batch.retain(|b| !b.coalesces_with(&c));
                batch.push(c);
            }
            for c in batch {
                let desc = format!("{c:?}");
                let r = crate::error::catch_panic(|| {
                    worker.handle(c, &sink);
                    Ok(())
                });
                if let Err(e) = r {
                    sink.log(
                        LogLevel::Error,
                        format!("worker {e} (while handling {desc})"),
                    );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::params::ImageBranchParams;
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
            h.send(Command::ApplySettings(RegisterParams {
                image: Some(ImageBranchParams {
                    k,
                    ..Default::default()
                }),
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
                Command::ApplySettings(s) => s.image.as_ref().map(|ib| ib.k),
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
}
