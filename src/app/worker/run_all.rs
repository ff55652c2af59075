//! "Run all": every pair of the dataset (or only those failed, in error or not run yet)
//! registered with the current parameters through the stage cache by the shared pair loop
//! (`pipeline::pair_loop`), one progress event before and after each pair, Cancel honoured
//! between pairs. Each pair fills its row of the pair browser (status, RRE, RTE, success,
//! inlier ratio, correspondences, time); a pair that fails or panics becomes an error row and
//! the run goes on. The current pair (and its model) is unchanged.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::model_build::fill_row;
use super::session::Registered;
use super::PipelineWorker;
use crate::app::channel::{EventSink, LogLevel, RunProgress, RunSelection, WorkerEvent};
use crate::app::model::{InspectorModel, PairEntry, PairOutcome, PairStatus};
use crate::pipeline::pair_loop::run_items;

/// What a run over the dataset did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunAllSummary {
    /// Pairs selected.
    pub total: usize,
    /// Pairs registered or recorded as errors before the run ended.
    pub done: usize,
    pub success: usize,
    pub failure: usize,
    pub errors: usize,
    /// Stopped by Cancel before every selected pair ran.
    pub cancelled: bool,
}

impl RunAllSummary {
    fn count(&mut self, row: &PairEntry) {
        self.done += 1;
        match row.outcome() {
            PairOutcome::Success => self.success += 1,
            PairOutcome::Failure => self.failure += 1,
            PairOutcome::Error => self.errors += 1,
            _ => {}
        }
    }
}

impl RunSelection {
    /// Whether a row is part of the selection; a row computed with other settings than
    /// `current` counts as not run.
    pub fn picks(self, row: &PairEntry, current: &str) -> bool {
        let stale = row.settings.as_ref().is_some_and(|s| s.id != current);
        match self {
            RunSelection::All => true,
            RunSelection::FailedOrPending if stale => true,
            RunSelection::FailedOrPending => matches!(
                row.outcome(),
                PairOutcome::Pending
                    | PairOutcome::Running
                    | PairOutcome::Failure
                    | PairOutcome::Error
            ),
        }
    }
}

impl PipelineWorker {
    /// The ids of the rows `sel` picks, in the dataset's order.
    pub fn selected_pairs(&self, sel: RunSelection) -> Vec<String> {
        let current = crate::app::model::SettingsTag::of(&self.params).id;
        self.pairs
            .iter()
            .filter(|p| sel.picks(p, &current))
            .map(|p| p.id.clone())
            .collect()
    }

    /// The rows of the pair browser.
    pub fn pair_rows(&self) -> &[PairEntry] {
        &self.pairs
    }

    /// Registers one pair with the current parameters (loaded pairs are reused, others loaded
    /// and not kept). `generate`: produce a missing generation (not for a Cosmos command, as in
    /// studies). Not guarded against panics: its callers run it in the
    /// [pair loop](crate::pipeline::pair_loop::run_items), whose guard turns one into an error.
    pub(super) fn run_row(&mut self, id: &str, generate: bool) -> crate::Result<Registered> {
        let pair = match self.loaded.get(id) {
            Some(p) => p.clone(),
            None => self.dataset.load_pair(id)?,
        };
        self.register(id, &pair, generate)
    }

    /// The row of pair `id` after [`run_row`](Self::run_row) gave `run` in `elapsed`: its
    /// numbers, or an error row saying why not, tagged with the current parameters.
    pub(super) fn pair_row(
        &self,
        id: &str,
        run: crate::Result<Registered>,
        elapsed: Duration,
    ) -> PairEntry {
        let mut row = self
            .pairs
            .iter()
            .find(|p| p.id == id)
            .cloned()
            .unwrap_or_else(|| PairEntry::pending(id, ""));
        match run {
            Ok(r) if self.params.image.is_some() && r.result.image.is_none() => {
                // the row must not show geometry-only numbers as the image branch's
                let why = r
                    .note
                    .unwrap_or_else(|| "the image branch did not run".to_string());
                row.reset(PairStatus::Failed(why));
                row.time_ms = Some(elapsed.as_secs_f64() * 1e3);
            }
            Ok(r) => fill_row(&mut row, &r.result),
            Err(e) => {
                row.reset(PairStatus::Failed(e.to_string()));
                row.time_ms = Some(elapsed.as_secs_f64() * 1e3);
            }
        }
        row.settings = Some(crate::app::model::SettingsTag::of(&self.params));
        row
    }

    /// Registers every pair `sel` picks, in the dataset's order, and fills their rows;
    /// `progress` hears of each pair before (no row) and after it runs (its row), and of the
    /// end (`finished`). Cancel ([`Worker::cancel_flag`](crate::app::Worker::cancel_flag))
    /// stops it between pairs. The current pair and its model stay as they are.
    pub fn run_all(
        &mut self,
        sel: RunSelection,
        progress: &mut dyn FnMut(RunProgress),
    ) -> RunAllSummary {
        self.cancel.store(false, Ordering::Relaxed);
        let ids = self.selected_pairs(sel);
        let generate = self.params.generates_missing();
        let total = ids.len();
        // the loop's state holds the worker mutably, so it reads the flag through its own Arc
        let cancel = self.cancel.clone();
        let mut state = (
            self,
            progress,
            RunAllSummary {
                total,
                ..Default::default()
            },
        );
        let end = run_items(
            &mut state,
            &ids,
            Some(&cancel),
            |(_, progress, _), i, id| {
                progress(RunProgress {
                    done: i,
                    total,
                    pair: id.clone(),
                    row: None,
                    finished: false,
                    cancelled: false,
                })
            },
            |(w, ..), _, id| w.run_row(id, generate),
            |(w, progress, summary), i, id, r, elapsed| {
                let row = w.pair_row(id, r, elapsed);
                summary.count(&row);
                if let Some(r) = w.pairs.iter_mut().find(|p| p.id == *id) {
                    *r = row.clone();
                }
                progress(RunProgress {
                    done: i + 1,
                    total,
                    pair: id.clone(),
                    row: Some(row),
                    finished: false,
                    cancelled: false,
                });
            },
        );
        let (_, progress, mut summary) = state;
        summary.cancelled = end.cancelled;
        // the last pair that ran ("" when none did)
        let last = end.ran.checked_sub(1).and_then(|i| ids.get(i));
        progress(RunProgress {
            done: summary.done,
            total: summary.total,
            pair: last.cloned().unwrap_or_default(),
            row: None,
            finished: true,
            cancelled: summary.cancelled,
        });
        summary
    }

    /// [`run_all`](Self::run_all) on the worker thread: progress events, a summary in the
    /// log, then the current model with the filled rows.
    pub(super) fn run_all_and_report(&mut self, sel: RunSelection, events: &EventSink) {
        let n = self.selected_pairs(sel).len();
        let what = match sel {
            RunSelection::All => "run all",
            RunSelection::FailedOrPending => "run failed/pending",
        };
        events.log(
            LogLevel::Info,
            format!("{what}: {n} pairs with the current settings…"),
        );
        let t = Instant::now();
        let s = self.run_all(sel, &mut |p| {
            if let Some(PairEntry {
                status: PairStatus::Failed(why),
                id,
                ..
            }) = &p.row
            {
                events.log(LogLevel::Warn, format!("{what}: {id}: {why}"));
            }
            events.send(WorkerEvent::RunAll(p))
        });
        events.log(
            LogLevel::Info,
            format!(
                "{what}: {} of {} pairs in {:.1} s: {} success, {} failure, {} error{}",
                s.done,
                s.total,
                t.elapsed().as_secs_f64(),
                s.success,
                s.failure,
                s.errors,
                if s.cancelled { " (cancelled)" } else { "" }
            ),
        );
        let pairs = self.pairs.clone();
        let model = match self.current.as_mut() {
            Some(c) => {
                c.model.pairs = pairs;
                c.model.clone()
            }
            // after an error row the pair stays selected
            None => InspectorModel {
                current_pair: self
                    .selected
                    .as_ref()
                    .and_then(|id| pairs.iter().position(|p| &p.id == id)),
                pairs,
                ..Default::default()
            },
        };
        events.send(WorkerEvent::Model(Box::new(model)));
    }
}
