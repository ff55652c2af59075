//! The plots panel's studies through the worker thread (the UI only sends a command), on the
//! bundled demo with the built-in generator (NOT a WFM) + XFeat and a temporary stage cache.
#![cfg(all(feature = "gui", feature = "onnx"))]

use crate::common;
use crate::common::demo_manifest;

use std::path::Path;
use std::time::{Duration, Instant};

use cgenreg::app::model::InspectorModel;
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{spawn_worker, Command, LogLevel, StudyRequest, WorkerEvent};
use cgenreg::cache::Cache;
use cgenreg::dataset::Dataset;
use cgenreg::pipeline::{RegisterParams, Registration, WfmSpec};

fn base() -> RegisterParams {
    common::demo_params(WfmSpec::Builtin)
}

#[test]
fn k_sweep_button_fills_the_plot_from_the_worker() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base()).unwrap();
    w.set_cache(Some(Cache::open(dir.path()).unwrap()));
    let params = base();
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::RunStudy(StudyRequest::K(vec![1, 2, 9]))));
    let t0 = Instant::now();
    let mut progress = Vec::new();
    let mut logs = Vec::new();
    let mut model: Option<Box<InspectorModel>> = None;
    while model.is_none() && t0.elapsed() < Duration::from_secs(600) {
        for e in h.poll() {
            match e {
                WorkerEvent::Progress(what, d, t) => progress.push((what, d, t)),
                WorkerEvent::Log(l, t) => logs.push((l, t)),
                WorkerEvent::Model(m) => model = Some(m),
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let m = model.unwrap_or_else(|| panic!("no model; log {logs:?}"));
    assert!(!logs.iter().any(|(l, _)| *l == LogLevel::Error), "{logs:?}");
    // progress of the two runnable (pair, K) runs, then the "finished" marker
    assert!(
        progress.contains(&("K sweep".to_string(), 2, 2)),
        "{progress:?}"
    );
    // K = 9 is invalid for L = 8, m = 1: logged as skipped, no point
    assert!(
        logs.iter()
            .any(|(l, t)| *l == LogLevel::Warn && t.contains("K = 9 skipped")),
        "{logs:?}"
    );
    let pts = &m.plots.vs_k;
    assert_eq!(pts.iter().map(|p| p.k).collect::<Vec<_>>(), vec![1, 2]);
    assert!(m.plots.vs_k_source.contains("builtin-depthshade-v1"));
    assert!(m.plots.vs_k_source.contains("xfeat@"));
    assert!(m.plots.study_progress.is_none());
    assert!(m.plots.prompt_study.is_empty());
    // each point is the pipeline's own result at that K
    let ds = Dataset::load(&demo_manifest()).unwrap();
    let pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    for p in pts {
        assert_eq!((p.pairs, p.skipped), (1, 0));
        let mut ib = params.image.clone().unwrap();
        ib.k = p.k;
        let q = RegisterParams {
            image: Some(ib),
            ..params.clone()
        };
        let r = Registration::new(&q).run(&pair).unwrap();
        let mm = r.metrics.unwrap();
        assert_eq!((p.rre_deg, p.rte_m), (mm.rre_deg, mm.rte_m), "K = {}", p.k);
        assert_eq!(p.recall, Some(if mm.success { 1.0 } else { 0.0 }));
    }
}

#[test]
fn study_without_a_wfm_only_warns() {
    let mut b = base();
    b.image = None;
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), b).unwrap();
    w.set_cache(None);
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::RunStudy(StudyRequest::Prompt)));
    let t0 = Instant::now();
    loop {
        let ev = h.poll();
        if let Some(t) = ev.iter().find_map(|e| match e {
            WorkerEvent::Log(LogLevel::Warn, t) => Some(t.clone()),
            _ => None,
        }) {
            assert!(t.contains("choose a WFM"), "{t}");
            break;
        }
        assert!(!ev.iter().any(|e| matches!(e, WorkerEvent::Model(_))));
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(10));
    }
}

// ---- start-up: the last opened data comes back (the demo when that fails) ----

use cgenreg::app::{save_persisted, startup_commands, OpenKind, Persisted};

#[test]
fn startup_reopens_the_last_data_or_falls_back_to_the_demo() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("inspector.json");
    // no settings file (or none at all): the demo pair
    let demo = Command::SelectPair("demo/0-1".into());
    assert_eq!(
        startup_commands(Some(&path), "demo/0-1"),
        vec![demo.clone()]
    );
    assert_eq!(startup_commands(None, "demo/0-1"), vec![demo.clone()]);
    save_persisted(&path, &Persisted::default()).unwrap();
    assert_eq!(
        startup_commands(Some(&path), "demo/0-1"),
        vec![demo.clone()]
    );
    // a Cosmos output folder is an image-branch setting, not data to reopen
    let p = Persisted {
        last_opened: Some((OpenKind::CosmosOutput, vec![dir.path().to_path_buf()])),
        ..Default::default()
    };
    save_persisted(&path, &p).unwrap();
    assert_eq!(startup_commands(Some(&path), "demo/0-1"), vec![demo]);
    // a persisted last-opened entry is reopened, with the demo pair as the fallback
    let missing = dir.path().join("gone.toml");
    let p = Persisted {
        last_opened: Some((OpenKind::Manifest, vec![missing.clone()])),
        ..Default::default()
    };
    save_persisted(&path, &p).unwrap();
    let cmds = startup_commands(Some(&path), "demo/0-1");
    assert_eq!(
        cmds,
        vec![Command::OpenOrFallback {
            kind: OpenKind::Manifest,
            paths: vec![missing],
            fallback_pair: "demo/0-1".into()
        }]
    );

    // through the worker: the missing file is logged as an error and the demo pair registers
    let mut b = base();
    b.image = None;
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), b).unwrap();
    w.set_cache(None);
    let fallback = w.pair_ids()[0].clone();
    let h = spawn_worker(Box::new(w), None);
    for c in startup_commands(Some(&path), &fallback) {
        assert!(h.send(c));
    }
    let (logs, m) = wait_for_done(&h);
    assert!(
        logs.iter()
            .any(|(l, t)| *l == LogLevel::Error && t.contains("gone.toml")),
        "{logs:?}"
    );
    let m = m.expect("the fallback pair registers");
    assert_eq!(m.pairs[m.current_pair.unwrap()].id, fallback);
    assert!(m.estimated.is_some());
}

/// Events until a model whose current pair is done (or failed), at most 300 s.
fn wait_for_done(
    h: &cgenreg::app::WorkerHandle,
) -> (Vec<(LogLevel, String)>, Option<Box<InspectorModel>>) {
    use cgenreg::app::model::PairStatus;
    let t0 = Instant::now();
    let mut logs = Vec::new();
    while t0.elapsed() < Duration::from_secs(300) {
        for e in h.poll() {
            match e {
                WorkerEvent::Log(l, t) => logs.push((l, t)),
                WorkerEvent::Model(m) => {
                    let st = m.current_pair.map(|i| m.pairs[i].status.clone());
                    if matches!(st, Some(PairStatus::Done) | Some(PairStatus::Failed(_))) {
                        return (logs, Some(m));
                    }
                }
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    (logs, None)
}

// ---- the Open dialog's "Cosmos output folder…" ----

use cgenreg::pipeline::params::cosmos_output_settings;
use cgenreg::wfm::cached::find_cosmos_spec;

const LINE: &str = r#"{"prompt": "a kitchen", "visual_input": "", "control_overrides": {"depth": {"input_control": "/d/000000_x.mp4", "control_weight": 1.0}}}"#;

#[test]
fn cosmos_spec_is_found_next_to_the_output_folder() {
    let root = tempfile::tempdir().unwrap();
    let mk = |p: &Path| std::fs::create_dir_all(p.join("video_0")).unwrap();
    // in the folder
    let a = root.path().join("a/out");
    mk(&a);
    std::fs::write(a.join("batch.jsonl"), LINE).unwrap();
    assert_eq!(find_cosmos_spec(&a).unwrap(), a.join("batch.jsonl"));
    // in the parent (a controlnet spec .json that is one JSON document is not a batch spec)
    let b = root.path().join("b/out");
    mk(&b);
    std::fs::write(root.path().join("b/spec.jsonl"), LINE).unwrap();
    std::fs::write(b.join("deafult_depth_gen_spec.json"), "{\n\"depth\": {}\n}").unwrap();
    assert_eq!(
        find_cosmos_spec(&b).unwrap(),
        root.path().join("b/spec.jsonl")
    );
    // the authors' layout: generation_specs/ next to generated_videos/, picked by name
    let c = root.path().join("c/generated_videos/3dmatch_rgb_gen_vids");
    mk(&c);
    let specs = root.path().join("c/generation_specs");
    std::fs::create_dir_all(&specs).unwrap();
    std::fs::write(specs.join("3dmatch_test.json"), LINE).unwrap();
    std::fs::write(specs.join("scannet_superglue_test.json"), LINE).unwrap();
    assert_eq!(
        find_cosmos_spec(&c).unwrap(),
        specs.join("3dmatch_test.json")
    );
    // several, none named like the folder: said so, with the files
    let d = root.path().join("d/out");
    mk(&d);
    std::fs::write(d.join("x.jsonl"), LINE).unwrap();
    std::fs::write(d.join("y.jsonl"), LINE).unwrap();
    let e = find_cosmos_spec(&d).unwrap_err().to_string();
    assert!(
        e.contains("several") && e.contains("x.jsonl") && e.contains("y.jsonl"),
        "{e}"
    );
    // none
    let n = root.path().join("n/out");
    mk(&n);
    let e = find_cosmos_spec(&n).unwrap_err().to_string();
    assert!(
        e.contains("no JSONL batch spec") && e.contains("n/out"),
        "{e}"
    );
    // not a Cosmos output folder
    let e = find_cosmos_spec(root.path()).unwrap_err().to_string();
    assert!(e.contains("video_<i>"), "{e}");

    // the settings change: cached Cosmos backend with folder + spec, nothing else
    let mut s0 = base();
    s0.image.as_mut().unwrap().k = 3;
    let s = cosmos_output_settings(&s0, &a).unwrap();
    assert_eq!(
        s.image.as_ref().unwrap().backend,
        WfmSpec::Cached {
            dir: a.clone(),
            spec: a.join("batch.jsonl")
        }
    );
    let mut back = s.clone();
    back.image.as_mut().unwrap().backend = s0.image.as_ref().unwrap().backend.clone();
    assert_eq!(back, s0);
}

#[test]
fn opening_a_cosmos_folder_switches_the_image_branch_and_keeps_the_dataset() {
    let root = tempfile::tempdir().unwrap();
    let out = root.path().join("out");
    std::fs::create_dir_all(out.join("video_0")).unwrap();
    std::fs::write(out.join("batch.jsonl"), LINE).unwrap();
    let mut b = base();
    b.image = None;
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), b).unwrap();
    w.set_cache(None);
    let ids = w.pair_ids();
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::Open {
        kind: OpenKind::CosmosOutput,
        paths: vec![out.clone()],
    }));
    let t0 = Instant::now();
    let mut settings = None;
    let mut logs: Vec<(LogLevel, String)> = Vec::new();
    let refused = |logs: &[(LogLevel, String)]| {
        logs.iter()
            .any(|(l, t)| *l == LogLevel::Error && t.contains("image branch cannot run"))
    };
    while !(settings.is_some() && refused(&logs)) && t0.elapsed() < Duration::from_secs(300) {
        for e in h.poll() {
            match e {
                WorkerEvent::Settings(s) => settings = Some(s),
                WorkerEvent::Log(l, t) => logs.push((l, t)),
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let s = settings.expect("the controls get the new settings");
    assert_eq!(
        s.image.as_ref().unwrap().backend,
        WfmSpec::Cached {
            dir: out.clone(),
            spec: out.join("batch.jsonl")
        }
    );
    // same dataset, same pair, re-run; this fake folder cannot feed the image branch, so the
    // pair is an error that says why (never a geometry-only result under the Cosmos label)
    let err = logs
        .iter()
        .find(|(l, t)| *l == LogLevel::Error && t.contains("image branch cannot run"))
        .map(|(_, t)| t.clone())
        .unwrap_or_else(|| panic!("no refusal; log {logs:?}"));
    assert!(err.contains(&ids[0]), "{err}");
    assert!(err.contains("Run geometry only"), "{err}");
    // a folder without a spec is refused with the reason; the settings stay
    let bad = root.path().join("bad");
    std::fs::create_dir_all(bad.join("video_0")).unwrap();
    assert!(h.send(Command::Open {
        kind: OpenKind::CosmosOutput,
        paths: vec![bad],
    }));
    let t0 = Instant::now();
    loop {
        let ev = h.poll();
        assert!(!ev.iter().any(|e| matches!(e, WorkerEvent::Settings(_))));
        if let Some(t) = ev.iter().find_map(|e| match e {
            WorkerEvent::Log(LogLevel::Error, t) => Some(t.clone()),
            _ => None,
        }) {
            assert!(t.contains("no JSONL batch spec"), "{t}");
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Figure 7 on request: a run leaves the curves pending (one curve, the current fusion's);
/// Command::Figure7 (sent by the plots panel) brings Noisy-AND and Noisy-OR, once.
#[test]
fn figure7_is_computed_when_the_plots_ask_for_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base()).unwrap();
    w.set_cache(Some(Cache::open(dir.path()).unwrap()));
    let id = w.pair_ids()[0].clone();
    let h = spawn_worker(Box::new(w), None);
    let wait_model = |what: &str| {
        let t0 = Instant::now();
        loop {
            for e in h.poll() {
                if let WorkerEvent::Model(m) = e {
                    return m;
                }
            }
            assert!(
                t0.elapsed() < Duration::from_secs(600),
                "no model for {what}"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    assert!(h.send(Command::SelectPair(id)));
    let m = wait_model("the run");
    assert!(m.plots.figure7_pending, "demo has GT and the image branch");
    assert_eq!(m.plots.pr_curves.len(), 1);
    assert!(h.send(Command::Figure7));
    let m = wait_model("figure 7");
    assert!(!m.plots.figure7_pending);
    let names: Vec<&str> = m.plots.pr_curves.iter().map(|c| c.name.as_str()).collect();
    assert!(
        names.len() == 2 && names[0].starts_with("Noisy-AND") && names[1].starts_with("Noisy-OR"),
        "{names:?}"
    );
    // Asked again: nothing to do, no new model.
    assert!(h.send(Command::Figure7));
    std::thread::sleep(Duration::from_millis(300));
    assert!(!h
        .poll()
        .into_iter()
        .any(|e| matches!(e, WorkerEvent::Model(_))));
}
