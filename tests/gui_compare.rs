//! The Compare tab driven through the app and the pipeline worker on real bench runs
//! (docs/ablation, redkitchen-rgbd): the comparison loads off the UI thread, its quadrant
//! counts are the library's and the files' own, and "open with B" hands run B's settings and
//! the pair to the worker. Skipped without the real data (failing under CI=true).
#![cfg(feature = "gui")]

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cgenreg::app::controls::{spawn_worker, Command, EventSink, Worker};
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{App, InspectorModel, Panel};
use cgenreg::metrics::compare::{compare, load_bench_run};
use cgenreg::pipeline::RegisterParams;
use eframe::egui;
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;

fn ablation(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("docs/ablation")
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
    if cgenreg::test_data_root().is_none() {
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
    while h.state().compare.loaded.is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the comparison never loaded: {:?}",
            h.state().compare.error
        );
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(10));
    }
    // the counts shown are the library's, and the files' own success fields
    let q = h
        .state()
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
        h.state().compare.rows().len(),
        q.only_a + q.only_b + q.both_failure
    );
    // the first row (flipped first) is a pair A solves and B does not
    let rows = h.state().compare.rows();
    let id = {
        let c = &h.state().compare.loaded.as_ref().unwrap().comparison;
        c.pairs[rows[0]].id.clone()
    };
    assert!(sa[&id] && !sb[&id], "{id}");
    // the table's row (the pair browser on the left lists the id too)
    h.query_all_by_label(&id).last().unwrap().click();
    h.run_steps(2);
    assert_eq!(h.state().compare.selected.as_deref(), Some(id.as_str()));
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
    while h.state().compare.is_loading() {
        assert!(t0.elapsed() < Duration::from_secs(30));
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(10));
    }
    let e = h.state().compare.error.clone().expect("an error");
    assert!(e.contains("not-a-run.json") && e.contains("pairs"), "{e}");
    assert!(h.state().compare.loaded.is_none());
}
