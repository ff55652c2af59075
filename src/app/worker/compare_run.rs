//! Two settings over the open dataset (the Compare tab's "Run A vs B"): each pair registered
//! with settings A, then with settings B, by the "Run all" machinery (loaded pairs reused,
//! the stage cache and the in-memory geometry shared by both), Cancel honoured between
//! registrations. The rows come back as two bench runs; the parameters in force, the pair
//! browser's rows and the current pair stay as they were.

use serde_json::json;

use super::PipelineWorker;
use crate::app::channel::{EventSink, LogLevel, WorkerEvent};
use crate::app::model::{CompareEvent, SettingsCompareRequest, SettingsRuns, Side};
use crate::app::model::{PairEntry, PairStatus};
use crate::pipeline::{RegisterParams, WfmSpec};
use crate::report::compare::{BenchRun, PairRow};

/// A pair browser row as a bench run's row (what `cgenreg bench --json` records per pair).
pub fn bench_row(e: &PairEntry) -> PairRow {
    let (success, error) = match &e.status {
        PairStatus::Failed(why) => (Some(false), Some(why.clone())),
        PairStatus::Done => (e.success, None),
        PairStatus::Pending | PairStatus::Running => (None, None),
    };
    PairRow {
        id: e.id.clone(),
        split: e.split.clone(),
        source: String::new(),
        target: String::new(),
        rre_deg: e.rre_deg,
        rte_m: e.rte_m,
        inlier_ratio: e.inlier_ratio,
        success,
        time_s: e.time_ms.unwrap_or(0.0) / 1e3,
        error,
        ..Default::default()
    }
}

/// A generation missing from the cache is produced, except by a Cosmos command (as in studies
/// and "Run all").
fn generates(p: &RegisterParams) -> bool {
    !matches!(
        p.image.as_ref().map(|i| &i.backend),
        Some(WfmSpec::Cosmos { .. })
    )
}

impl PipelineWorker {
    /// The bench run of `rows` made with `params` on the open dataset.
    fn settings_bench_run(
        &self,
        label: &str,
        params: &RegisterParams,
        rows: Vec<PairRow>,
    ) -> BenchRun {
        let manifest = self
            .dataset
            .manifest
            .as_ref()
            .map(|m| m.display().to_string());
        BenchRun {
            label: label.to_string(),
            params: serde_json::to_value(params).unwrap_or_default(),
            identity: json!({
                "manifest": manifest,
                "dataset": self.dataset.name,
                "made": "inspector, over the open dataset",
            }),
            manifest,
            pairs: rows,
        }
    }

    /// Registers `req`'s pairs with settings A and with settings B (A then B per pair);
    /// `progress` hears before each registration. Cancel stops it between registrations: the
    /// runs then hold the pairs done under both settings.
    pub fn compare_settings(
        &mut self,
        req: &SettingsCompareRequest,
        progress: &mut dyn FnMut(CompareEvent),
    ) -> SettingsRuns {
        use std::sync::atomic::Ordering;
        self.cancel.store(false, Ordering::Relaxed);
        let ids: Vec<String> = match &req.pairs {
            Some(ids) => ids.clone(),
            None => self.pairs.iter().map(|p| p.id.clone()).collect(),
        };
        let saved = self.params.clone();
        let total = 2 * ids.len();
        let (mut rows_a, mut rows_b) = (Vec::new(), Vec::new());
        let mut cancelled = false;
        'pairs: for (i, id) in ids.iter().enumerate() {
            // loaded once for both settings (kept only while they run, as "Run all" keeps none)
            let keep = !self.loaded.contains_key(id);
            if keep {
                if let Ok(p) = self.dataset.load_pair(id) {
                    self.loaded.insert(id.clone(), p);
                }
            }
            let mut rows = Vec::with_capacity(2);
            for (k, (side, params)) in [(Side::A, &req.a), (Side::B, &req.b)]
                .into_iter()
                .enumerate()
            {
                if self.cancel.load(Ordering::Relaxed) {
                    cancelled = true;
                    if keep {
                        self.loaded.remove(id);
                    }
                    break 'pairs;
                }
                progress(CompareEvent::Progress {
                    side,
                    pair: id.clone(),
                    done: 2 * i + k,
                    total,
                });
                self.params = params.clone();
                rows.push(bench_row(&self.run_row(id, generates(params))));
            }
            if keep {
                self.loaded.remove(id);
            }
            if let (Some(b), Some(a)) = (rows.pop(), rows.pop()) {
                rows_a.push(a);
                rows_b.push(b);
            }
        }
        self.params = saved;
        SettingsRuns {
            a: self.settings_bench_run("settings A", &req.a, rows_a),
            b: self.settings_bench_run("settings B", &req.b, rows_b),
            request: req.clone(),
            cancelled,
        }
    }

    /// [`compare_settings`](Self::compare_settings) on the worker thread: progress events,
    /// a line in the log, and the two runs for the Compare tab.
    pub(super) fn compare_settings_and_report(
        &mut self,
        req: SettingsCompareRequest,
        events: &EventSink,
    ) {
        let n = req.pairs.as_ref().map_or(self.pairs.len(), |p| p.len());
        events.log(
            LogLevel::Info,
            format!("compare settings: {n} pairs with settings A, then B…"),
        );
        let t = std::time::Instant::now();
        let runs = self.compare_settings(&req, &mut |e| events.send(WorkerEvent::Compare(e)));
        let errors = runs
            .a
            .pairs
            .iter()
            .chain(&runs.b.pairs)
            .filter(|r| r.error.is_some())
            .count();
        events.log(
            if errors > 0 {
                LogLevel::Warn
            } else {
                LogLevel::Info
            },
            format!(
                "compare settings: {} pairs in {:.1} s, {errors} registrations failed{}",
                runs.a.pairs.len().min(runs.b.pairs.len()),
                t.elapsed().as_secs_f64(),
                if runs.cancelled { " (cancelled)" } else { "" }
            ),
        );
        events.send(WorkerEvent::Compare(CompareEvent::Finished(Box::new(runs))));
    }
}
