//! The plots panel's studies through the worker thread (the UI only sends a command), on the
//! bundled demo with the built-in generator (NOT a WFM) + XFeat and a temporary stage cache.
#![cfg(all(feature = "gui", feature = "onnx"))]

use std::path::Path;
use std::time::{Duration, Instant};

use cgenreg::app::model::InspectorModel;
use cgenreg::app::pipeline_worker::{params_to_settings, settings_to_params, PipelineWorker};
use cgenreg::app::{spawn_worker, Command, LogLevel, StudyRequest, WorkerEvent};
use cgenreg::dataset::Dataset;
use cgenreg::pipeline::cache::Cache;
use cgenreg::pipeline::image_branch::register_with_image;
use cgenreg::pipeline::{ImageBranchParams, RegisterParams, WfmSpec};

fn demo_manifest() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml")
}

fn base() -> RegisterParams {
    RegisterParams {
        voxel: 0.05,
        image: Some(ImageBranchParams {
            backend: WfmSpec::Builtin,
            frames_per_fragment: 8,
            margin: 1,
            k: 2,
            ..Default::default()
        }),
        ..Default::default()
    }
}

#[test]
fn k_sweep_button_fills_the_plot_from_the_worker() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base()).unwrap();
    w.set_cache(Some(Cache::open(dir.path()).unwrap()));
    let params = settings_to_params(&params_to_settings(&base()), &base());
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
    assert!(
        !logs.iter().any(|(l, _)| *l == LogLevel::Error),
        "{logs:?}"
    );
    // progress of the two runnable (pair, K) runs, then the "finished" marker
    assert!(progress.contains(&("K sweep".to_string(), 2, 2)), "{progress:?}");
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
        let r = register_with_image(&pair, &params, &ib, None).unwrap();
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
