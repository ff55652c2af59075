//! Two settings over the open dataset (the Compare tab's "Run A vs B"): each pair registered
//! with settings A, then with settings B, by the "Run all" machinery as items of the shared
//! pair loop (`pipeline::pair_loop`): loaded pairs reused, the stage cache and the in-memory
//! geometry shared by both, Cancel honoured between registrations. The rows come back as two
//! bench runs; the parameters in force, the pair browser's rows and the current pair stay as
//! they were.

use std::sync::atomic::Ordering;

use serde_json::json;

use super::PipelineWorker;
use crate::app::channel::{EventSink, LogLevel, WorkerEvent};
use crate::app::model::{CompareEvent, SettingsCompareRequest, SettingsRuns, Side};
use crate::app::model::{PairEntry, PairStatus};
use crate::pipeline::pair_loop::run_items;
use crate::pipeline::RegisterParams;
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

/// A settings comparison's state, shared by the pair loop's hooks.
struct Comparing<'a> {
    worker: &'a mut PipelineWorker,
    progress: &'a mut dyn FnMut(CompareEvent),
    /// The pair loaded for this comparison (dropped after its B, or when the loop stops).
    loaded_here: Option<String>,
    /// The current pair's row under A, waiting for its B.
    row_a: Option<PairRow>,
    rows_a: Vec<PairRow>,
    rows_b: Vec<PairRow>,
}

impl Comparing<'_> {
    fn drop_loaded(&mut self) {
        if let Some(id) = self.loaded_here.take() {
            self.worker.loaded.remove(&id);
        }
    }
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
        self.cancel.store(false, Ordering::Relaxed);
        let ids: Vec<String> = match &req.pairs {
            Some(ids) => ids.clone(),
            None => self.pairs.iter().map(|p| p.id.clone()).collect(),
        };
        let saved = self.params.clone();
        // one registration per item: pair i under A, then under B
        let items: Vec<(&str, Side, &RegisterParams)> = ids
            .iter()
            .flat_map(|id| {
                [
                    (id.as_str(), Side::A, &req.a),
                    (id.as_str(), Side::B, &req.b),
                ]
            })
            .collect();
        let total = items.len();
        let cancel = self.cancel.clone();
        let mut state = Comparing {
            worker: self,
            progress,
            loaded_here: None,
            row_a: None,
            rows_a: Vec::new(),
            rows_b: Vec::new(),
        };
        let end = run_items(
            &mut state,
            &items,
            Some(&cancel),
            |s, i, (id, side, _)| {
                (s.progress)(CompareEvent::Progress {
                    side: *side,
                    pair: id.to_string(),
                    done: i,
                    total,
                })
            },
            |s, _, (id, side, params)| {
                // loaded once for both settings (kept only while they run, as "Run all" keeps
                // none); a load that fails is the registration's error
                if *side == Side::A && !s.worker.loaded.contains_key(*id) {
                    if let Ok(p) = s.worker.dataset.load_pair(id) {
                        s.worker.loaded.insert(id.to_string(), p);
                        s.loaded_here = Some(id.to_string());
                    }
                }
                s.worker.params = (*params).clone();
                s.worker.run_row(id, params.generates_missing())
            },
            |s, _, (id, side, _), r, elapsed| {
                let row = bench_row(&s.worker.pair_row(id, r, elapsed));
                match side {
                    Side::A => s.row_a = Some(row),
                    Side::B => {
                        if let Some(a) = s.row_a.take() {
                            s.rows_a.push(a);
                            s.rows_b.push(row);
                        }
                        s.drop_loaded();
                    }
                }
            },
        );
        // cancelled between a pair's A and B: that pair is in neither run, nor kept loaded
        state.drop_loaded();
        let Comparing {
            worker,
            rows_a,
            rows_b,
            ..
        } = state;
        worker.params = saved;
        SettingsRuns {
            a: worker.settings_bench_run("settings A", &req.a, rows_a),
            b: worker.settings_bench_run("settings B", &req.b, rows_b),
            request: req.clone(),
            cancelled: end.cancelled,
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
