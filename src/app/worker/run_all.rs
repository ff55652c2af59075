//! "Run all": every pair of the dataset (or only those failed, in error or not run yet)
//! registered with the current parameters through the stage cache, one progress event per
//! pair, Cancel honoured between pairs. Each pair fills its row of the pair browser (status,
//! RRE, RTE, success, inlier ratio, correspondences, time); a pair that fails or panics
//! becomes an error row and the run goes on. The current pair (and its model) is unchanged.

use std::time::Instant;

use super::model_build::fill_row;
use super::PipelineWorker;
use crate::app::channel::{EventSink, LogLevel, RunProgress, RunSelection, WorkerEvent};
use crate::app::model::{InspectorModel, PairEntry, PairOutcome, PairStatus};
use crate::pipeline::WfmSpec;

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

    /// One pair's row: registered with the current parameters (loaded pairs are reused, others
    /// loaded and not kept), or an error row saying why not. `generate`: produce a missing
    /// generation (not for a Cosmos command, as in studies).
    pub(super) fn run_row(&mut self, id: &str, generate: bool) -> PairEntry {
        let mut row = self
            .pairs
            .iter()
            .find(|p| p.id == id)
            .cloned()
            .unwrap_or_else(|| PairEntry::pending(id, ""));
        let t = Instant::now();
        let run = crate::error::catch_panic(|| {
            let pair = match self.loaded.get(id) {
                Some(p) => p.clone(),
                None => self.dataset.load_pair(id)?,
            };
            self.register(id, &pair, generate)
        });
        match run {
            Ok(r) if self.params.image.is_some() && r.result.image.is_none() => {
                // the row must not show geometry-only numbers as the image branch's
                let why = r
                    .note
                    .unwrap_or_else(|| "the image branch did not run".to_string());
                row.reset(PairStatus::Failed(why));
                row.time_ms = Some(t.elapsed().as_secs_f64() * 1e3);
            }
            Ok(r) => fill_row(&mut row, &r.result),
            Err(e) => {
                row.reset(PairStatus::Failed(e.to_string()));
                row.time_ms = Some(t.elapsed().as_secs_f64() * 1e3);
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
        use std::sync::atomic::Ordering;
        self.cancel.store(false, Ordering::Relaxed);
        let ids = self.selected_pairs(sel);
        let generate = !matches!(
            self.params.image.as_ref().map(|i| &i.backend),
            Some(WfmSpec::Cosmos { .. })
        );
        let mut summary = RunAllSummary {
            total: ids.len(),
            ..Default::default()
        };
        let mut last = String::new();
        for (i, id) in ids.iter().enumerate() {
            if self.cancel.load(Ordering::Relaxed) {
                summary.cancelled = true;
                break;
            }
            progress(RunProgress {
                done: i,
                total: ids.len(),
                pair: id.clone(),
                row: None,
                finished: false,
                cancelled: false,
            });
            let row = self.run_row(id, generate);
            summary.count(&row);
            if let Some(r) = self.pairs.iter_mut().find(|p| p.id == *id) {
                *r = row.clone();
            }
            progress(RunProgress {
                done: i + 1,
                total: ids.len(),
                pair: id.clone(),
                row: Some(row),
                finished: false,
                cancelled: false,
            });
            last = id.clone();
        }
        progress(RunProgress {
            done: summary.done,
            total: summary.total,
            pair: last,
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
            None => InspectorModel {
                pairs,
                ..Default::default()
            },
        };
        events.send(WorkerEvent::Model(Box::new(model)));
    }
}
