//! The inspector on a real registration: the bundled synthetic demo pair is registered by
//! `register_pair`, converted into the model, checked against brute force, and rendered.

use std::path::Path;
use std::time::{Duration, Instant};

use cgenreg::app::colormap::{SOURCE_RGB, TARGET_RGB};
use cgenreg::app::headless::render_screenshot;
use cgenreg::app::model::{PairStatus, StageState};
use cgenreg::app::pipeline_worker::{
    result_to_model, settings_to_params, PipelineWorker, GT_INLIER_M, IMAGE_BRANCH_OFF,
};
use cgenreg::app::{spawn_worker, Command, Panel, WorkerEvent};
use cgenreg::dataset::manifest::Dataset;
use cgenreg::pipeline::{register_pair, RegisterParams};
use nalgebra::Point3;

fn demo_manifest() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml")
}

fn params() -> RegisterParams {
    let mut p = RegisterParams::default();
    p.fusion.selection = cgenreg::fusion::select::Selection::RowNn;
    p
}

#[test]
fn registration_result_becomes_a_consistent_model() {
    let ds = Dataset::load(&demo_manifest()).unwrap();
    let id = ds.pairs()[0].id.clone();
    let pair = ds.load_pair(&id).unwrap();
    let res = register_pair(&pair, &params()).unwrap();
    let model = result_to_model(&pair, &res, "geometry", Vec::new());

    // keypoints first, then a bounded display subsample
    let (ns, nt) = (res.source_keypoints.len(), res.target_keypoints.len());
    assert!(model.source.len() > ns && model.target.len() > nt);
    assert!(model.source.len() <= ns + cgenreg::app::pipeline_worker::DISPLAY_POINTS + 1);
    for (i, p) in res.source_keypoints.iter().enumerate() {
        assert_eq!(model.source[i], [p.x, p.y, p.z]);
    }
    // every correspondence, with GT flags recomputed by brute force
    assert_eq!(model.matches.len(), res.correspondences.len());
    let gt = pair.gt_target_from_source.unwrap();
    let mut inl = 0;
    for (m, c) in model.matches.iter().zip(&res.correspondences) {
        assert_eq!((m.src, m.tgt), (c.src as usize, c.tgt as usize));
        let s = res.source_keypoints[m.src];
        let t = res.target_keypoints[m.tgt];
        let d = (gt * Point3::new(s.x as f64, s.y as f64, s.z as f64)
            - Point3::new(t.x as f64, t.y as f64, t.z as f64))
        .norm();
        assert_eq!(m.inlier_gt, Some(d < GT_INLIER_M));
        inl += (d < GT_INLIER_M) as usize;
    }
    assert!(
        inl > 0,
        "no GT inliers among {} matches",
        model.matches.len()
    );
    let kept = model
        .matches
        .iter()
        .filter(|m| m.survived == Some(true))
        .count();
    assert_eq!(kept, res.inliers.len());
    // transforms, pair row, stages, plots, views
    assert_eq!(model.estimated, Some(res.estimate));
    assert_eq!(model.ground_truth, Some(gt));
    let row = &model.pairs[model.current_pair.unwrap()];
    assert_eq!(row.id, id);
    assert_eq!(row.status, PairStatus::Done);
    let m = res.metrics.as_ref().unwrap();
    assert_eq!(row.rre_deg, Some(m.rre_deg));
    assert_eq!(row.rte_m, Some(m.rte_m));
    assert!(m.rre_deg < 5.0 && m.rte_m < 0.2, "demo pair failed: {m:?}");
    assert_eq!(model.stages.len(), res.timings.len());
    for (s, t) in model.stages.iter().zip(&res.timings) {
        assert_eq!(s.name, t.stage);
        assert_eq!(s.time_ms, Some(t.ms));
        assert!(matches!(s.state, StageState::Done | StageState::Cached));
    }
    let pr = &model.plots.pr_curves[0].points;
    assert!(
        (pr.last().unwrap()[0] - 1.0).abs() < 1e-9,
        "recall must reach 1"
    );
    assert!(
        (pr.last().unwrap()[1] - inl as f64 / model.matches.len() as f64).abs() < 1e-9,
        "precision at full recall is the inlier ratio"
    );
    if res.image.is_none() {
        assert!(model.source_views.is_empty() && model.target_views.is_empty());
        assert_eq!(model.image_branch_note.as_deref(), Some(IMAGE_BRANCH_OFF));
    }

    // the 3D panel shows both clouds in their colours (skipped without EGL unless CI)
    if cgenreg::app::headless::HeadlessGl::new((64, 64)).is_err() {
        assert!(std::env::var("CI").is_err(), "CI needs EGL for screenshots");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo3d.png");
    render_screenshot(&model, Panel::View3d, (1024, 640), &out).unwrap();
    let img = image::open(&out).unwrap().to_rgba8();
    let near = |c: [u8; 3]| {
        img.pixels()
            .filter(|p| (0..3).all(|k| (p.0[k] as i32 - c[k] as i32).abs() <= 6))
            .count()
    };
    let (ys, bs) = (near(SOURCE_RGB), near(TARGET_RGB));
    assert!(ys > 2000, "too few yellow source pixels: {ys}");
    assert!(bs > 2000, "too few blue target pixels: {bs}");
}

#[test]
fn worker_registers_on_the_worker_thread_and_reports_posteriors() {
    let worker = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
    let id = worker.pair_ids()[0].clone();
    // settings map back onto the same parameters
    let p = settings_to_params(worker.settings(), &params());
    assert_eq!(p.fusion.selection, params().fusion.selection);
    assert_eq!(p.fusion.calibration_geo, params().fusion.calibration_geo);

    // a bad pair id fails in the UI, not with a panic
    let handle = spawn_worker(Box::new(worker), None);
    // (queued selections coalesce, so the good one is sent once the bad one is answered)
    handle.send(Command::SelectPair("nope/1-2".into()));
    let t0 = Instant::now();
    let mut error_logged = false;
    while !error_logged && t0.elapsed() < Duration::from_secs(60) {
        for e in handle.poll() {
            if let WorkerEvent::Log(cgenreg::app::LogLevel::Error, t) = e {
                error_logged |= t.contains("nope/1-2");
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    handle.send(Command::SelectPair(id.clone()));
    let t0 = Instant::now();
    let mut model = None;
    while model.is_none() && t0.elapsed() < Duration::from_secs(300) {
        for e in handle.poll() {
            match e {
                WorkerEvent::Log(cgenreg::app::LogLevel::Error, t) => {
                    error_logged |= t.contains("nope/1-2")
                }
                WorkerEvent::Model(m) if m.current_pair.is_some_and(|i| m.pairs[i].id == id) => {
                    if m.pairs[m.current_pair.unwrap()].status == PairStatus::Done {
                        model = Some(m)
                    }
                }
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(error_logged, "the failing pair was not reported");
    let model = model.expect("no model from the worker");
    let m = model
        .matches
        .iter()
        .find(|m| m.survived == Some(true))
        .unwrap()
        .clone();
    handle.send(Command::InspectSourcePoint(m.src));
    let t0 = Instant::now();
    let mut post = None;
    while post.is_none() && t0.elapsed() < Duration::from_secs(120) {
        for e in handle.poll() {
            if let WorkerEvent::Model(mm) = e {
                post = mm.posterior_for(m.src).cloned();
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let post = post.expect("no posterior");
    assert!(post.image.is_empty(), "image branch is off");
    assert_eq!(post.fused, post.geometric);
    let s: f32 = post.geometric.iter().sum();
    assert!(s > 0.0 && s <= 1.0 + 1e-4, "posterior mass {s}");
    // the GT target is the nearest target keypoint to T_gt * source point (brute force)
    let gt = model.ground_truth.unwrap();
    let sp = model.source[m.src];
    let q = gt * Point3::new(sp[0] as f64, sp[1] as f64, sp[2] as f64);
    let n_tgt_kp = model.matches.iter().map(|m| m.tgt).max().unwrap() + 1;
    let best = (0..model.target.len())
        .filter(|&j| j < n_tgt_kp.max(post.gt_target.unwrap() + 1))
        .min_by(|&a, &b| {
            let d = |j: usize| {
                let t = model.target[j];
                (Point3::new(t[0] as f64, t[1] as f64, t[2] as f64) - q).norm()
            };
            d(a).total_cmp(&d(b))
        })
        .unwrap();
    let dist = |j: usize| {
        let t = model.target[j];
        (Point3::new(t[0] as f64, t[1] as f64, t[2] as f64) - q).norm()
    };
    assert!(dist(post.gt_target.unwrap()) <= dist(best) + 1e-9);
}

/// The image branch in the worker: oracle views on the demo pair through a fresh stage cache;
/// a temperature change re-runs only fusion onward from memory; a new prompt whose generation
/// is not cached shows no views and asks for the generator; a pair without enough frames falls
/// back to the geometric branch with the reason.
#[test]
fn worker_runs_the_image_branch_from_the_cache_and_refuses_from_memory() {
    use cgenreg::app::controls::WfmChoice;
    use cgenreg::pipeline::{ImageBranchParams, WfmSpec};
    let dir = tempfile::tempdir().unwrap();
    let mut base = RegisterParams::default();
    base.image = Some(ImageBranchParams {
        backend: WfmSpec::Oracle,
        frames_per_fragment: 8,
        margin: 1,
        k: 2,
        ..Default::default()
    });
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base.clone()).unwrap();
    w.set_cache(Some(
        cgenreg::pipeline::cache::Cache::open(dir.path()).unwrap(),
    ));
    assert_eq!(w.settings().wfm, WfmChoice::Oracle);
    let id = w.pair_ids()[0].clone();
    let m = w.run_pair(&id).unwrap();
    assert_eq!((m.source_views.len(), m.target_views.len()), (2, 2));
    assert!(m.source_views[0].label.backend.contains("oracle"));
    assert!(m.generation_missing.is_none());
    assert!(m
        .stages
        .iter()
        .any(|s| s.name == "generation" && s.state == StageState::Done));
    // second full run: the image stages come from the cache
    let m = w.run_pair(&id).unwrap();
    assert!(m
        .stages
        .iter()
        .any(|s| s.name == "generation" && s.state == StageState::Cached));
    // temperature change: fusion onward from memory, views kept
    let mut s = w.settings().clone();
    s.geometry_calibration.temperature = 0.05;
    w.set_settings(s.clone());
    let m = w
        .refuse()
        .expect("same image settings: re-fuse from memory")
        .unwrap();
    assert_eq!(m.source_views.len(), 2);
    assert!(m
        .stages
        .iter()
        .any(|s| s.name == "fusion" && s.state == StageState::Done));
    assert!(m
        .stages
        .iter()
        .any(|s| s.name == "vfm source views" && s.state == StageState::Cached));
    // posterior with the image branch: image row and pixels in the views
    let src = m
        .matches
        .iter()
        .find(|x| x.survived == Some(true))
        .unwrap()
        .src;
    let m = w.inspect_point(src).unwrap();
    let p = m.posterior_for(src).unwrap();
    assert_eq!(p.image.len(), p.candidates.len());
    assert!(p
        .fused
        .iter()
        .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    // a new prompt: not generated without asking, no views from the old prompt
    s.prompt_scene = "a snowy pine forest".into();
    w.set_settings(s);
    assert!(w.refuse().is_none(), "a new prompt needs the image stages");
    let m = w.run_pair_with(&id, false).unwrap();
    assert!(m.generation_missing.is_some());
    assert!(m.source_views.is_empty() && m.target_views.is_empty());
    assert!(m
        .image_branch_note
        .as_deref()
        .unwrap()
        .contains("Run the generator"));
    assert!(
        m.estimated.is_some(),
        "the geometric branch still registers"
    );
    // the generator runs on request
    let m = w.run_pair_with(&id, true).unwrap();
    assert_eq!(m.source_views.len(), 2);
    // too few frames for L: geometry only, with the reason
    base.image.as_mut().unwrap().frames_per_fragment = 50;
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base).unwrap();
    w.set_cache(None);
    let m = w.run_pair(&id).unwrap();
    assert!(m.source_views.is_empty());
    let note = m.image_branch_note.unwrap();
    assert!(note.contains("fell back to the geometric branch"), "{note}");
    assert!(m.estimated.is_some());
}
