//! The Compare tab driven through the app and the pipeline worker on real bench runs
//! (studies/ablation/results, redkitchen-rgbd): the comparison loads off the UI thread, its quadrant
//! counts are the library's and the files' own, and "open with B" hands run B's settings and
//! the pair to the worker. Skipped without the real data (failing under CI=true).
#![cfg(feature = "gui")]

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cgenreg::app::channel::{spawn_worker, Command, EventSink, Worker};
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{App, InspectorModel, Panel};
use cgenreg::pipeline::RegisterParams;
use cgenreg::report::compare::{compare, load_bench_run};
use eframe::egui;
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;

fn ablation(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("studies/ablation/results")
        .join(name)
}

/// The pipeline worker, recording the commands it got and the parameters in force after each.
struct Spy {
    inner: PipelineWorker,
    seen: Arc<Mutex<Vec<(Command, RegisterParams)>>>,
}

impl Worker for Spy {
    fn handle(&mut self, command: Command, events: &EventSink) {
        let c = command.clone();
        self.inner.handle(command, events);
        self.seen
            .lock()
            .unwrap()
            .push((c, self.inner.params().clone()));
    }
}

/// Success per pair id, read straight from a bench JSON.
fn successes(path: &Path) -> std::collections::HashMap<String, bool> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    v["pairs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r["id"].as_str().unwrap().to_string(),
                r["success"].as_bool().unwrap(),
            )
        })
        .collect()
}

#[test]
fn compare_two_real_runs_and_open_a_pair_with_run_b() {
    if cgenreg::testing::test_data_root().is_none() {
        return;
    }
    // A: FPFH NN; B: FPFH, mutual NN (both geometry only, so opening a pair is a quick
    // registration in a debug build)
    let (pa, pb) = (ablation("fpfh-nn.json"), ablation("fpfh-mutual.json"));
    let run_a = load_bench_run(&pa).unwrap();
    let run_b = load_bench_run(&pb).unwrap();
    let manifest = run_a.resolve_manifest(&pa).expect("the runs' manifest");
    let seen = Arc::new(Mutex::new(Vec::new()));
    let worker = PipelineWorker::open_manifest(&manifest, RegisterParams::default()).unwrap();
    let model = worker.initial_model(None);
    let handle = spawn_worker(
        Box::new(Spy {
            inner: worker,
            seen: seen.clone(),
        }),
        None,
    );
    let mut app = App::new(model, Some(handle), None);
    app.allow_dialogs = false;
    app.compare_runs(pa.clone(), pb.clone());
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .with_pixels_per_point(1.0)
        .build_ui_state(|ui, app: &mut App| app.show(ui), app);
    h.run_steps(1);
    assert_eq!(h.state().ui_state.tab, Panel::Compare);
    let t0 = Instant::now();
    while h.state().tabs.compare.loaded.is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the comparison never loaded: {:?}",
            h.state().tabs.compare.error
        );
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(10));
    }
    // the counts shown are the library's, and the files' own success fields
    let q = h
        .state()
        .tabs
        .compare
        .loaded
        .as_ref()
        .unwrap()
        .comparison
        .quadrants;
    assert_eq!(q, compare(&run_a, &run_b).quadrants);
    let (sa, sb) = (successes(&pa), successes(&pb));
    let count = |x: bool, y: bool| sa.iter().filter(|(id, s)| **s == x && sb[*id] == y).count();
    assert_eq!(
        (q.both_success, q.only_a, q.only_b, q.both_failure),
        (
            count(true, true),
            count(true, false),
            count(false, true),
            count(false, false)
        )
    );
    assert!(q.only_a > 0, "FPFH NN succeeds where mutual NN fails");
    for (label, n) in [
        ("both succeed", q.both_success),
        ("A only", q.only_a),
        ("B only", q.only_b),
        ("both fail", q.both_failure),
    ] {
        h.get_by_label(&format!("{label}: {n}"));
    }
    // a quadrant filter: only the pairs lost by B stay in the table
    h.get_by_label(&format!("both succeed: {}", q.both_success))
        .click();
    h.run_steps(2);
    assert_eq!(
        h.state().tabs.compare.rows().len(),
        q.only_a + q.only_b + q.both_failure
    );
    // the first row (flipped first) is a pair A solves and B does not
    let rows = h.state().tabs.compare.rows();
    let id = {
        let c = &h.state().tabs.compare.loaded.as_ref().unwrap().comparison;
        c.pairs[rows[0]].id.clone()
    };
    assert!(sa[&id] && !sb[&id], "{id}");
    // the table's row (the pair browser on the left lists the id too)
    h.query_all_by_label(&id).last().unwrap().click();
    h.run_steps(2);
    assert_eq!(
        h.state().tabs.compare.selected.as_deref(),
        Some(id.as_str())
    );
    h.get_by_label("open with B").click();
    h.run_steps(2);
    let b_params = run_b.register_params().unwrap();
    assert_eq!(
        h.state().params,
        b_params,
        "the controls show run B's settings"
    );
    assert_eq!(h.state().ui_state.tab, Panel::Views);
    // the worker registers the pair with B's settings
    let t0 = Instant::now();
    loop {
        h.run_steps(1);
        let done = seen.lock().unwrap().iter().find_map(|(c, p)| match c {
            Command::OpenPairWith { pair, .. } if *pair == id => Some(p.clone()),
            _ => None,
        });
        if let Some(p) = done {
            assert_eq!(p, b_params, "the worker's parameters are run B's");
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(600),
            "the worker never handled the open; log: {:?}",
            h.state().log.iter().map(|l| &l.text).collect::<Vec<_>>()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // the model shows the pair, registered under B's settings
    let t0 = Instant::now();
    loop {
        h.run_steps(1);
        let m = h.state().model();
        if let Some((p, rre)) = m
            .current_pair
            .map(|i| &m.pairs[i])
            .filter(|p| p.id == id)
            .and_then(|p| Some((p, p.rre_deg?)))
        {
            let rec = run_b.pairs.iter().find(|r| r.id == id).unwrap();
            eprintln!(
                "{id} with run B's settings: RRE {rre:.2} deg here, {:.2} deg in {}",
                rec.rre_deg.unwrap(),
                pb.display()
            );
            // the run's outcome comes back: the pair B lost fails here too
            let success = rre <= cgenreg::metrics::RECALL_RRE_DEG
                && p.rte_m.unwrap() <= cgenreg::metrics::RECALL_RTE_M;
            assert_eq!(Some(success), rec.success);
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no model for {id}; log: {:?}",
            h.state().log.iter().map(|l| &l.text).collect::<Vec<_>>()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A file that is not a bench run: the error names the file and the field, and nothing loads.
#[test]
fn a_bad_run_file_is_reported_with_its_name_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("not-a-run.json");
    std::fs::write(&bad, br#"{"params": {}, "pairs": [{"id": 1}]}"#).unwrap();
    let mut app = App::new(InspectorModel::demo(), None, None);
    app.allow_dialogs = false;
    app.compare_runs(ablation("fpfh-nn.json"), bad.clone());
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .build_ui_state(|ui, app: &mut App| app.show(ui), app);
    let t0 = Instant::now();
    while h.state().tabs.compare.is_loading() {
        assert!(t0.elapsed() < Duration::from_secs(30));
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(10));
    }
    let e = h.state().tabs.compare.error.clone().expect("an error");
    assert!(e.contains("not-a-run.json") && e.contains("pairs"), "{e}");
    assert!(h.state().tabs.compare.loaded.is_none());
}

/// A geometry-only worker on the staged redkitchen manifest with its own empty stage cache.
fn staged_worker(cache: &Path) -> PipelineWorker {
    let manifest =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-staged.toml");
    let mut w = PipelineWorker::open_manifest(&manifest, RegisterParams::default()).unwrap();
    assert!(w.params().image.is_none(), "the default runs geometry only");
    w.set_cache(Some(cgenreg::cache::Cache::open(cache).unwrap()));
    w
}

/// Settings B of the settings comparisons: A with row NN instead of mutual NN (a fusion
/// setting that changes geometry-only results, as fpfh-nn against fpfh-mutual shows).
fn settings_b(a: &RegisterParams) -> RegisterParams {
    let mut b = a.clone();
    b.fusion.selection = match a.fusion.selection {
        cgenreg::fusion::Selection::RowNn => cgenreg::fusion::Selection::MutualNn,
        _ => cgenreg::fusion::Selection::RowNn,
    };
    b
}

/// "Compare two settings over the open dataset": settings A and B taken from the controls,
/// "Run A vs B" over the first three staged pairs on the worker, and the compare view of the
/// two runs, saying what differs; each row is what registering that pair alone with those
/// settings gives, and the worker's settings and pair rows are left as they were.
#[test]
fn compare_two_settings_over_the_open_dataset() {
    if cgenreg::testing::test_data_root().is_none() {
        return;
    }
    let cache = tempfile::tempdir().unwrap();
    let worker = staged_worker(cache.path());
    let model = worker.initial_model(None);
    let a = worker.params().clone();
    let b = settings_b(&a);
    let ids: Vec<String> = model.pairs[..3].iter().map(|p| p.id.clone()).collect();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let handle = spawn_worker(
        Box::new(Spy {
            inner: worker,
            seen: seen.clone(),
        }),
        None,
    );
    let mut app = App::new(model, Some(handle), None);
    app.allow_dialogs = false;
    app.ui_state.tab = Panel::Compare;
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .with_pixels_per_point(1.0)
        .build_ui_state(|ui, app: &mut App| app.show(ui), app);
    h.run_steps(2);
    // nothing to run before both settings are taken
    assert!(h
        .state()
        .tabs
        .compare
        .settings
        .request(h.state().model())
        .is_none());
    h.state_mut().params = a.clone();
    h.run_steps(1);
    h.get_by_label("take A from the controls").click();
    h.run_steps(2);
    h.state_mut().params = b.clone();
    h.get_by_label("take B from the controls").click();
    h.run_steps(2);
    assert_eq!(h.state().tabs.compare.settings.a.as_ref(), Some(&a));
    assert_eq!(h.state().tabs.compare.settings.b.as_ref(), Some(&b));
    // what differs is said before the run
    h.get_by_label_contains("A and B differ in fusion.selection");
    h.state_mut().tabs.compare.settings.limit = 3;
    h.run_steps(2);
    h.get_by_label("Run A vs B").click();
    h.run_steps(2);
    let t0 = Instant::now();
    let mut saw_progress = false;
    while h.state().tabs.compare.loaded.is_none() {
        saw_progress |= h.state().tabs.compare.settings.progress.is_some();
        assert!(
            t0.elapsed() < Duration::from_secs(600),
            "the comparison never came back; log: {:?}",
            h.state().log.iter().map(|l| &l.text).collect::<Vec<_>>()
        );
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(saw_progress, "a progress bar while the worker runs");
    assert!(h.state().tabs.compare.settings.progress.is_none());
    let l = h.state().tabs.compare.loaded.clone().unwrap();
    let c = &l.comparison;
    let got: Vec<&str> = c.pairs.iter().map(|p| p.id.as_str()).collect();
    assert_eq!(got, ids.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(c.only_in_a.is_empty() && c.only_in_b.is_empty());
    assert_eq!(c.differing_settings, vec!["fusion.selection".to_string()]);
    assert!(c.run_differences.is_empty(), "{:?}", c.run_differences);
    assert_eq!(l.a.params.as_ref().ok(), Some(&a));
    assert_eq!(l.b.params.as_ref().ok(), Some(&b));
    assert!(l.a.path.is_none() && l.a.name == "settings A");
    let q = c.quadrants;
    assert_eq!(
        q.both_success + q.only_a + q.only_b + q.both_failure + q.unknown,
        3
    );
    // the view shows it as it shows two files: counts, and what differs
    h.run_steps(2);
    h.get_by_label(&format!("both succeed: {}", q.both_success));
    h.get_by_label("the runs differ only in: fusion.selection");
    // the worker's own settings and pair rows are unchanged
    let rows: Vec<_> = h.state().model().pairs[..3]
        .iter()
        .map(|p| p.status.clone())
        .collect();
    assert!(
        rows.iter()
            .all(|s| *s == cgenreg::app::model::PairStatus::Pending),
        "{rows:?}"
    );
    {
        let seen = seen.lock().unwrap();
        let (cmd, after) = seen.last().expect("the worker handled the comparison");
        assert!(matches!(cmd, Command::CompareSettings(_)), "{cmd:?}");
        assert_eq!(after, &a, "the worker's settings are restored");
    }
    // each row is the pair registered alone with that run's settings (the first pair, under B)
    let mut alone = staged_worker(cache.path());
    alone.set_params(b.clone());
    let m = alone.run_pair(&ids[0]).unwrap();
    let row = &m.pairs[m.current_pair.unwrap()];
    let p = &c.pairs[0];
    assert_eq!(p.b.rre_deg, row.rre_deg, "{}", p.id);
    assert_eq!(p.b.rte_m, row.rte_m);
    assert_eq!(p.b.success, row.success);
}

/// Cancel during a settings comparison stops it between registrations; the runs hold the
/// pairs done under both settings, and the worker's settings are restored.
#[test]
fn a_cancelled_settings_comparison_keeps_the_pairs_run_under_both() {
    if cgenreg::testing::test_data_root().is_none() {
        return;
    }
    let cache = tempfile::tempdir().unwrap();
    let mut w = staged_worker(cache.path());
    let a = w.params().clone();
    let b = settings_b(&a);
    let ids = w.pair_ids()[..3].to_vec();
    let req = cgenreg::app::tabs::compare::SettingsCompareRequest {
        a: a.clone(),
        b: b.clone(),
        pairs: Some(ids.clone()),
    };
    let cancel = w.cancel_flag().unwrap();
    let mut events = Vec::new();
    let runs = w.compare_settings(&req, &mut |e| {
        // Cancel while the second pair runs under A: it stops before its B
        if let cgenreg::app::tabs::compare::CompareEvent::Progress { done: 2, .. } = &e {
            cancel.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        events.push(e);
    });
    assert!(runs.cancelled);
    assert_eq!(events.len(), 3, "{events:?}");
    let got: Vec<&str> = runs.a.pairs.iter().map(|r| r.id.as_str()).collect();
    assert_eq!(got, vec![ids[0].as_str()]);
    assert_eq!(runs.b.pairs.len(), 1);
    assert_eq!(w.params(), &a);
    let c = compare(&runs.a, &runs.b);
    assert_eq!(c.pairs.len(), 1);
    assert_eq!(c.differing_settings, vec!["fusion.selection".to_string()]);
}
