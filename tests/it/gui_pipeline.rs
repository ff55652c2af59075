//! The inspector on a real registration: the bundled synthetic demo pair is registered by
//! `register_pair`, converted into the model, checked against brute force, and rendered.
#![cfg(feature = "gui")]

use crate::common;
use crate::common::demo_manifest;

use std::path::Path;
use std::time::{Duration, Instant};

use cgenreg::app::colormap::{SOURCE_RGB, TARGET_RGB};
use cgenreg::app::model::{PairStatus, StageState};
use cgenreg::app::worker::{
    result_to_model, PipelineWorker, ViewMemo, IMAGE_BRANCH_OFF, VIEW_MEMO,
};
use cgenreg::app::{spawn_worker, Command, Panel, WorkerEvent};
use cgenreg::dataset::manifest::Dataset;
use cgenreg::pipeline::{RegisterParams, Registration};
use nalgebra::Point3;

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
    let res = Registration::new(&params()).run(&pair).unwrap();
    let model = result_to_model(
        &pair,
        &res,
        "geometry",
        Vec::new(),
        &mut ViewMemo::new(VIEW_MEMO),
    );

    // keypoints first, then a bounded display subsample
    let (ns, nt) = (res.source_keypoints.len(), res.target_keypoints.len());
    assert!(model.source.len() > ns && model.target.len() > nt);
    assert!(model.source.len() <= ns + cgenreg::app::worker::DISPLAY_POINTS + 1);
    for (i, p) in res.source_keypoints.iter().enumerate() {
        assert_eq!(model.source[i], [p.x, p.y, p.z]);
    }
    // every correspondence, with GT flags recomputed by brute force
    assert_eq!(model.matches.len(), res.correspondences.len());
    let gt = pair.gt_target_from_source.unwrap();
    // judged by the run's inlier threshold (the indoor preset's 0.10 m here)
    let within = res.gt_inlier_threshold_m;
    assert_eq!(within, params().inlier_threshold_m());
    assert_eq!(
        (model.gt_inlier_m, model.gt_inlier_label().as_str()),
        (within, "10 cm")
    );
    let mut inl = 0;
    for (m, c) in model.matches.iter().zip(&res.correspondences) {
        assert_eq!((m.src, m.tgt), (c.src as usize, c.tgt as usize));
        let s = res.source_keypoints[m.src];
        let t = res.target_keypoints[m.tgt];
        let d = (gt * Point3::new(s.x as f64, s.y as f64, s.z as f64)
            - Point3::new(t.x as f64, t.y as f64, t.z as f64))
        .norm();
        assert_eq!(m.inlier_gt, Some(d < within));
        inl += (d < within) as usize;
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
    // unshaded points (the default eye-dome lighting darkens edges): the colours themselves
    cgenreg::app::headless::render_screenshot_with(
        &model,
        Panel::View3d,
        (1024, 640),
        &out,
        |app| {
            app.view3d_prefs_mut().depth_cue = cgenreg::app::render3d::DepthCue::None;
        },
    )
    .unwrap();
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
    // the worker runs the parameters it was given (fusion shows what a geometry-only run does)
    let p = worker.params();
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
                WorkerEvent::Model(m)
                    if m.current_pair.is_some_and(|i| {
                        m.pairs[i].id == id && m.pairs[i].status == PairStatus::Done
                    }) =>
                {
                    model = Some(m)
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
/// The worker keeps the plan its run filled (every key known, even without a stage cache) and
/// compares a settings change with it: a temperature re-fuses from memory, K needs a run.
#[test]
fn worker_without_a_cache_compares_changes_with_the_plan_its_run_filled() {
    use cgenreg::pipeline::{StageName, WfmSpec};
    let mut w =
        PipelineWorker::open_manifest(&demo_manifest(), common::demo_params(WfmSpec::Builtin))
            .unwrap();
    w.set_cache(None);
    let id = w.pair_ids()[0].clone();
    let m = w.run_pair(&id).unwrap();
    // every stage row of the run names its stage; the tail's rows are the fusion stage's
    let typed: Vec<_> = m.stages.iter().filter_map(|s| s.stage).collect();
    assert!(typed.contains(&StageName::Generation) && typed.contains(&StageName::Fusion));
    assert!(m
        .stages
        .iter()
        .filter(|s| s.name == "estimate" || s.name == "generation")
        .all(|s| s.stage.is_some()));
    let mut s = w.params().clone();
    *s.fusion.calibration_img.tau_mut() = 0.05;
    w.set_params(s.clone());
    let m = w
        .refuse_from_memory()
        .expect("only the fusion key changed: re-fuse from memory")
        .unwrap();
    assert_eq!(m.stages[0].name, "re-fuse from memory");
    assert_eq!(
        m.stages[1].name,
        "settings change invalidated: similarity, fusion and estimation"
    );
    // the kept stages before the tail are shown as cached, the tail's ran again
    assert!(m
        .stages
        .iter()
        .any(|r| r.stage == Some(StageName::Generation) && r.state == StageState::Cached));
    assert!(m
        .stages
        .iter()
        .any(|r| r.stage == Some(StageName::Fusion) && r.state == StageState::Done));
    s.image.as_mut().unwrap().k = 1;
    w.set_params(s);
    assert!(
        w.refuse_from_memory().is_none(),
        "K re-runs the image branch"
    );
}

#[test]
fn worker_runs_the_image_branch_from_the_cache_and_refuses_from_memory() {
    use cgenreg::pipeline::WfmSpec;
    let dir = tempfile::tempdir().unwrap();
    let mut base = common::demo_params(WfmSpec::Oracle);
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base.clone()).unwrap();
    w.set_cache(Some(cgenreg::cache::Cache::open(dir.path()).unwrap()));
    assert_eq!(w.params().image.as_ref().unwrap().backend, WfmSpec::Oracle);
    let id = w.pair_ids()[0].clone();
    let m = w.run_pair(&id).unwrap();
    assert_eq!((m.source_views.len(), m.target_views.len()), (2, 2));
    assert!(m.source_views[0].label.backend.contains("oracle"));
    assert!(m.generation_missing.is_none());
    // Figure 7 from the kept similarities: Noisy-AND and Noisy-OR, recall up to 1.
    let curves = w
        .fusion_pr_curves()
        .expect("image branch + GT give both curves");
    assert_eq!(curves.len(), 2);
    assert!(curves[0].name.starts_with("Noisy-AND") && curves[1].name.starts_with("Noisy-OR"));
    for c in &curves {
        assert!(c
            .points
            .iter()
            .all(|p| (0.0..=1.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1])));
        assert!((c.points.last().unwrap()[0] - 1.0).abs() < 1e-9);
    }
    // Each view carries the depth frame it came from, its camera and what it sees.
    for (views, cloud) in [(&m.source_views, &m.source), (&m.target_views, &m.target)] {
        for v in views {
            let d = v.depth.as_ref().expect("depth frame a click away");
            assert_eq!((d.width, d.height), (640, 480), "the sensor depth frame");
            let cam = v.camera.as_ref().expect("view camera");
            assert_eq!(cam.camera.name(), "pinhole");
            assert_eq!(v.point_state.len(), cloud.len());
            let seen = v.point_state.iter().filter(|&&s| s == 2).count();
            // The view's own scan is fused from its frames: a good part of it is in sight.
            assert!(seen * 10 > cloud.len(), "{seen} of {} visible", cloud.len());
            // A visible point projects inside the image, in front of the camera.
            let i = v.point_state.iter().position(|&s| s == 2).unwrap();
            let p = cloud[i];
            let pc = cam.cloud_from_camera.inverse()
                * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let (u, vv) = cam.camera.project(&pc).unwrap();
            assert!(pc.z > 0.0 && u > -1.0 && vv > -1.0 && u < 641.0 && vv < 481.0);
        }
    }
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
    let mut s = w.params().clone();
    *s.fusion.calibration_geo.tau_mut() = 0.05;
    w.set_params(s.clone());
    let m = w
        .refuse_from_memory()
        .expect("same image settings: re-fuse from memory")
        .unwrap();
    assert_eq!(m.source_views.len(), 2);
    // the stage keys were compared and the panel names what the change invalidated
    assert_eq!(m.stages[0].name, "re-fuse from memory");
    assert_eq!(
        m.stages[1].name,
        "settings change invalidated: similarity, fusion and estimation"
    );
    assert_eq!(
        m.stages
            .iter()
            .filter(|s| s.name.starts_with("settings change"))
            .count(),
        1
    );
    assert!(m
        .stages
        .iter()
        .any(|s| s.name == "fusion" && s.state == StageState::Done));
    assert!(m
        .stages
        .iter()
        .any(|s| s.name == "vfm source views" && s.state == StageState::Cached));
    // the default fusion with the image branch (union) records its own tail timings: a
    // re-fusion lists each stage once, the kept tail not beside the new one
    let mut u = s.clone();
    u.fusion.mode = cgenreg::fusion::FusionMode::Union;
    w.set_params(u.clone());
    // a full run under the union (the image stages from the cache), then a re-fusion
    w.run_pair(&id).unwrap();
    *u.fusion.calibration_geo.tau_mut() = 0.07;
    w.set_params(u);
    let mu = w
        .refuse_from_memory()
        .expect("temperature change re-fuses")
        .unwrap();
    let mut names: Vec<&str> = mu.stages.iter().map(|s| s.name.as_str()).collect();
    assert!(names.contains(&"fusion: noisy-and"), "{names:?}");
    names.sort();
    let n = names.len();
    names.dedup();
    assert_eq!(names.len(), n, "a stage listed twice after a re-fusion");
    w.set_params(s.clone());
    let m = w.refuse_from_memory().expect("back to Noisy-AND").unwrap();
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
    s.image.as_mut().unwrap().prompt.scene = "a snowy pine forest".into();
    w.set_params(s);
    assert!(
        w.refuse_from_memory().is_none(),
        "a new prompt needs the image stages"
    );
    // the pair is an error until the generator runs, never a geometry-only result under
    // the image branch's label
    let e = w.run_pair_with(&id, false).unwrap_err();
    assert!(
        matches!(e, cgenreg::Error::GenerationNotCached { .. }),
        "{e}"
    );
    // the generator runs on request
    let m = w.run_pair_with(&id, true).unwrap();
    assert_eq!(m.source_views.len(), 2);
    // too few frames for L: an error with the reason, no geometry-only result
    base.image.as_mut().unwrap().frames_per_fragment = 50;
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), base).unwrap();
    w.set_cache(None);
    let e = w.run_pair(&id).unwrap_err().to_string();
    assert!(
        e.contains("image branch cannot run") && e.contains("L = 50") && e.contains("WFM:"),
        "{e}"
    );
    assert!(w.result().is_none());
}

// ---- opening data through Command::Open (file dialogs and drag-and-drop end here) ----

use cgenreg::app::channel::WorkerHandle;
use cgenreg::app::model::InspectorModel;
use cgenreg::app::{LogLevel, OpenKind};

/// Events until a model whose current pair finished (done or failed) or an error log.
fn wait_for_result(
    handle: &WorkerHandle,
    secs: u64,
) -> (Vec<(LogLevel, String)>, Option<Box<InspectorModel>>) {
    let t0 = Instant::now();
    let mut logs = Vec::new();
    while t0.elapsed() < Duration::from_secs(secs) {
        for e in handle.poll() {
            match e {
                WorkerEvent::Log(l, t) => {
                    let err = l == LogLevel::Error;
                    logs.push((l, t));
                    if err {
                        return (logs, None);
                    }
                }
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
    panic!("no result from the worker in {secs} s; log: {logs:?}");
}

fn open(handle: &WorkerHandle, kind: OpenKind, paths: Vec<std::path::PathBuf>) {
    assert!(handle.send(Command::Open { kind, paths }));
}

fn rot_deg(a: &nalgebra::Isometry3<f64>, b: &nalgebra::Isometry3<f64>) -> f64 {
    (a.rotation.inverse() * b.rotation).angle().to_degrees()
}

/// The demo target fragment saved as `tgt.ply`, a transformed copy as `src.ply` (p_tgt = T
/// p_src) and T as `gt.txt`.
fn write_two_clouds(dir: &Path) -> nalgebra::Isometry3<f64> {
    let ds = Dataset::load(&demo_manifest()).unwrap();
    let id = ds.pairs()[0].target.clone();
    let target = ds.load_fragment(&id).unwrap().cloud;
    let t = nalgebra::Isometry3::new(
        nalgebra::Vector3::new(0.3, -0.2, 0.15),
        nalgebra::Vector3::new(0.1, 0.35, -0.05),
    );
    let inv = t.inverse().cast::<f32>();
    let mut source = target.clone();
    for p in source.points.iter_mut() {
        *p = inv * *p;
    }
    source.normals = None;
    cgenreg::io::cloud::save_cloud(&dir.join("tgt.ply"), &target).unwrap();
    cgenreg::io::cloud::save_cloud(&dir.join("src.ply"), &source).unwrap();
    cgenreg::camera::camera_txt::write_pose(&dir.join("gt.txt"), &t).unwrap();
    t
}

#[test]
fn open_two_cloud_files_registers_them_against_the_gt() {
    let dir = tempfile::tempdir().unwrap();
    let t = write_two_clouds(dir.path());
    let worker = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
    let handle = spawn_worker(Box::new(worker), None);
    // a drop in arbitrary order: names decide source and target, the .txt is the GT
    let paths = vec![
        dir.path().join("tgt.ply"),
        dir.path().join("gt.txt"),
        dir.path().join("src.ply"),
    ];
    assert_eq!(
        cgenreg::dataset::open::classify_drop(&paths),
        OpenKind::TwoClouds
    );
    open(&handle, OpenKind::Auto, paths);
    let (logs, m) = wait_for_result(&handle, 300);
    let m = m.unwrap_or_else(|| panic!("open failed: {logs:?}"));
    assert_eq!(m.pairs.len(), 1);
    assert_eq!(m.pairs[0].id, "files/tgt-src");
    assert_eq!(m.pairs[0].status, PairStatus::Done);
    let gt = m.ground_truth.expect("GT from gt.txt");
    assert!(
        rot_deg(&gt, &t) < 1e-6 && (gt.translation.vector - t.translation.vector).norm() < 1e-6
    );
    let est = m.estimated.expect("an estimate");
    let (rre, rte) = (
        rot_deg(&est, &t),
        (est.translation.vector - t.translation.vector).norm(),
    );
    assert!(rre < 2.0 && rte < 0.05, "RRE {rre}° RTE {rte} m");
    assert_eq!(
        m.pairs[0].rre_deg.map(|r| (r - rre).abs() < 1e-6),
        Some(true)
    );
}

#[test]
fn a_bad_open_is_logged_and_keeps_the_previous_dataset() {
    let dir = tempfile::tempdir().unwrap();
    write_two_clouds(dir.path());
    let bad = dir.path().join("broken.ply");
    std::fs::write(
        &bad,
        b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n",
    )
    .unwrap();
    let empty = tempfile::tempdir().unwrap();
    let worker = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
    let old = worker.pair_ids();
    let handle = spawn_worker(Box::new(worker), None);
    let cases: Vec<(OpenKind, Vec<std::path::PathBuf>, Vec<&str>)> = vec![
        (
            OpenKind::TwoClouds,
            vec![bad.clone(), dir.path().join("tgt.ply")],
            vec!["broken.ply", "previous dataset stays open"],
        ),
        (
            OpenKind::TwoClouds,
            vec![dir.path().join("missing.ply"), dir.path().join("tgt.ply")],
            vec!["missing.ply", "point-cloud file"],
        ),
        (
            OpenKind::TwoClouds,
            vec![
                dir.path().join("src.ply"),
                dir.path().join("tgt.ply"),
                dir.path().join("broken.txt"),
            ],
            vec!["broken.txt"],
        ),
        (
            OpenKind::ThreeDMatchFolder,
            vec![empty.path().to_path_buf()],
            vec!["cloud_bin_"],
        ),
        (
            OpenKind::RgbdSequence,
            vec![empty.path().to_path_buf()],
            vec!["camera-intrinsics.txt"],
        ),
        (
            OpenKind::Manifest,
            vec![dir.path().join("gt.txt")],
            vec!["gt.txt", "manifest"],
        ),
        (
            OpenKind::Auto,
            vec![dir.path().join("src.ply")],
            vec!["src.ply", "two cloud files"],
        ),
    ];
    std::fs::write(dir.path().join("broken.txt"), "1 0 0\n").unwrap();
    for (kind, paths, want) in cases {
        open(&handle, kind, paths.clone());
        let (logs, m) = wait_for_result(&handle, 120);
        assert!(m.is_none(), "{kind:?} {paths:?} gave a model");
        let (l, text) = logs.last().unwrap();
        assert_eq!(*l, LogLevel::Error);
        for w in want {
            assert!(text.contains(w), "{kind:?}: {text:?} lacks {w:?}");
        }
        assert!(!text.contains("panicked"), "{text}");
    }
    // the demo dataset is still the one loaded
    handle.send(Command::SelectPair(old[0].clone()));
    let (logs, m) = wait_for_result(&handle, 300);
    let m = m.unwrap_or_else(|| panic!("old pair did not run: {logs:?}"));
    assert_eq!(
        m.pairs.iter().map(|p| p.id.clone()).collect::<Vec<_>>(),
        old
    );
    assert_eq!(m.pairs[m.current_pair.unwrap()].status, PairStatus::Done);
}

/// The staged 3DMatch files are spread over folders named after their source repositories;
/// a 3DMatch-style folder is assembled from links (no copies) to fragments 0 and 5 and gt.log.
#[test]
fn open_a_threedmatch_folder() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let m3 = root.join("3dmatch-redkitchen");
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("redkitchen");
    std::fs::create_dir(&scene).unwrap();
    for (link, to) in [
        ("cloud_bin_0.pth", "regtr/cloud_bin_0.pth"),
        ("cloud_bin_5.pth", "regtr/cloud_bin_5.pth"),
        ("gt.log", "benchmark/3DMatch/gt.log"),
    ] {
        std::os::unix::fs::symlink(m3.join(to), scene.join(link)).unwrap();
    }
    let worker = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
    let handle = spawn_worker(Box::new(worker), None);
    // the staged folder itself is not 3DMatch-style: a clear error
    open(&handle, OpenKind::ThreeDMatchFolder, vec![m3.clone()]);
    let (logs, m) = wait_for_result(&handle, 60);
    assert!(m.is_none());
    assert!(logs.last().unwrap().1.contains("cloud_bin_"), "{logs:?}");
    // dropped folder: classified, opened, first pair registered with the gt.log GT
    assert_eq!(
        cgenreg::dataset::open::classify_drop(std::slice::from_ref(&scene)),
        OpenKind::ThreeDMatchFolder
    );
    open(&handle, OpenKind::Auto, vec![scene.clone()]);
    let (logs, m) = wait_for_result(&handle, 300);
    let m = m.unwrap_or_else(|| panic!("open failed: {logs:?}"));
    let row = &m.pairs[m.current_pair.unwrap()];
    assert_eq!(m.pairs.len(), 1);
    assert_eq!(row.id, "redkitchen/0-5");
    assert_eq!(row.status, PairStatus::Done);
    let log = cgenreg::io::gtlog::read_gt_log(&m3.join("benchmark/3DMatch/gt.log")).unwrap();
    let e = log.iter().find(|e| (e.target, e.source) == (0, 5)).unwrap();
    let gt = m.ground_truth.unwrap();
    assert!(rot_deg(&gt, &e.target_from_source) < 1e-9);
    // 3DMatch's success thresholds (measured: about 1.5° / 5 cm)
    assert!(row.rre_deg.unwrap() < 15.0 && row.rte_m.unwrap() < 0.3);
    eprintln!(
        "3DMatch 0-5: RRE {:?} RTE {:?}, {} matches",
        row.rre_deg,
        row.rte_m,
        m.matches.len()
    );
}

/// A raw RGB-D sequence: fragments of 50 frames, neighbouring fragments paired, GT from the
/// poses (equal to 3DMatch's gt.log `0 1`, as the data's INDEX.md states).
#[test]
fn open_an_rgbd_sequence() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let seq = root.join("7scenes-redkitchen-rgbd");
    let ds =
        cgenreg::dataset::open::open_dataset(OpenKind::RgbdSequence, std::slice::from_ref(&seq))
            .unwrap()
            .with_fragment_cache(Some(
                cgenreg::cache::Cache::open(cgenreg::cache::default_cache_dir()).unwrap(),
            ));
    let n = ds.pairs().len();
    assert_eq!(n, 9, "500 frames: 10 fragments, 9 neighbouring pairs");
    let spec = &ds.pairs()[0];
    assert_eq!(spec.id, "7scenes-redkitchen-rgbd/0-1");
    let pair = ds.load_pair(&spec.id).unwrap();
    for (scan, first) in [(&pair.target, 0), (&pair.source, 50)] {
        let f = scan.frames.as_ref().expect("frames of the fragment");
        assert_eq!(f.frames.len(), 50);
        assert_eq!(f.frames[0].index, first);
        assert!(f.frames[0].color_path.is_some());
        assert!(scan.cloud.len() > 10_000, "{} points", scan.cloud.len());
    }
    let gt = pair.gt_target_from_source.unwrap();
    let log =
        cgenreg::io::gtlog::read_gt_log(&root.join("3dmatch-redkitchen/benchmark/3DMatch/gt.log"))
            .unwrap();
    let e = log.iter().find(|e| (e.target, e.source) == (0, 1)).unwrap();
    assert!(rot_deg(&gt, &e.target_from_source) < 1e-4);
    assert!((gt.translation.vector - e.target_from_source.translation.vector).norm() < 1e-4);

    // through the worker (the fragments now come from the fragment cache)
    assert_eq!(
        cgenreg::dataset::open::classify_drop(std::slice::from_ref(&seq)),
        OpenKind::RgbdSequence
    );
    let worker = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
    let handle = spawn_worker(Box::new(worker), None);
    open(&handle, OpenKind::Auto, vec![seq]);
    let (logs, m) = wait_for_result(&handle, 600);
    let m = m.unwrap_or_else(|| panic!("open failed: {logs:?}"));
    assert_eq!(m.pairs.len(), n);
    let row = &m.pairs[m.current_pair.unwrap()];
    assert_eq!(row.id, spec.id);
    assert_eq!(row.status, PairStatus::Done);
    assert!(rot_deg(&m.ground_truth.unwrap(), &gt) < 1e-9);
    assert!(row.rre_deg.unwrap() < 15.0 && row.rte_m.unwrap() < 0.3);
    eprintln!("7-Scenes 0-1: RRE {:?} RTE {:?}", row.rre_deg, row.rte_m);
}

/// A re-fusion from memory (kept row maxima, the estimate memo) gives, bit for bit, what the
/// library's `refuse_from_memory` gives from the kept similarities, and the registration a fresh
/// run gives (same correspondences, same pose); repeating the settings reuses the estimate.
#[test]
fn refusion_from_memory_equals_the_library_and_a_fresh_run() {
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
    let id = w.pair_ids()[0].clone();
    w.run_pair(&id).unwrap();
    let mut s = w.params().clone();
    *s.fusion.calibration_geo.tau_mut() = 0.07;
    w.set_params(s.clone());
    let kept = w
        .refuse_from_memory()
        .expect("a temperature change re-fuses")
        .unwrap();

    let ds = Dataset::load(&demo_manifest()).unwrap();
    let pair = ds.load_pair(&id).unwrap();
    let reg = cgenreg::pipeline::Registration::new(&s).keep(true);
    let mut fresh = reg.run(&pair).unwrap();
    let inputs = fresh.inputs.take().unwrap();
    let sims = cgenreg::pipeline::tail::similarities(&inputs).unwrap();
    let lib = reg.refuse_from_memory(&pair, &inputs, Some(&sims)).unwrap();
    let lib = result_to_model(
        &pair,
        &lib,
        "lib",
        Vec::new(),
        &mut ViewMemo::new(VIEW_MEMO),
    );
    let key = |m: &cgenreg::app::InspectorModel| {
        m.matches
            .iter()
            .map(|c| (c.src, c.tgt, c.score.to_bits(), c.survived))
            .collect::<Vec<_>>()
    };
    assert!(!kept.matches.is_empty());
    assert_eq!(key(&kept), key(&lib));
    let pose = |m: &cgenreg::app::InspectorModel| m.estimated.map(|e| e.to_homogeneous());
    assert_eq!(pose(&kept), pose(&lib));
    // a fresh run (streaming similarity): the same correspondences and pose
    let mut a: Vec<(u32, u32)> = fresh
        .correspondences
        .iter()
        .map(|c| (c.src, c.tgt))
        .collect();
    let mut b: Vec<(u32, u32)> = kept
        .matches
        .iter()
        .map(|c| (c.src as u32, c.tgt as u32))
        .collect();
    a.sort_unstable();
    b.sort_unstable();
    assert_eq!(a, b);
    let d = (fresh.estimate.to_homogeneous() - kept.estimated.unwrap().to_homogeneous())
        .abs()
        .max();
    assert!(d < 1e-6, "poses differ by {d}");

    let estimate_row = |m: &cgenreg::app::InspectorModel| {
        m.stages
            .iter()
            .find(|r| r.name == "estimate")
            .map(|r| r.state.clone())
    };
    // the demo has 16k correspondences: the temperature changes which 8000 (max_points) of them
    // SC2-PCR uses, so it runs again
    assert_eq!(estimate_row(&kept), Some(StageState::Done));
    // the same settings again: the same correspondences, so the estimate is remembered
    w.set_params(s);
    let again = w.refuse_from_memory().expect("re-fuse").unwrap();
    assert_eq!(key(&again), key(&kept));
    assert_eq!(pose(&again), pose(&kept));
    assert_eq!(estimate_row(&again), Some(StageState::Cached));
}

/// When SC2-PCR uses every correspondence, a temperature change under NN selection keeps their
/// set (the row softmax is monotone) and the first run's estimate is reused: the same pose as
/// the library's fresh estimate at the new temperature.
#[test]
fn a_temperature_change_under_nn_reuses_the_first_runs_estimate() {
    let mut p = params();
    p.estimator = cgenreg::estimate::EstimatorKind::Sc2Pcr(cgenreg::estimate::Sc2PcrParams {
        max_points: 20_000,
        ..Default::default()
    });
    let mut w = PipelineWorker::open_manifest(&demo_manifest(), p).unwrap();
    let id = w.pair_ids()[0].clone();
    let first = w.run_pair(&id).unwrap();
    let mut s = w.params().clone();
    *s.fusion.calibration_geo.tau_mut() = 0.07;
    w.set_params(s.clone());
    let kept = w
        .refuse_from_memory()
        .expect("a temperature change re-fuses")
        .unwrap();
    let row = kept.stages.iter().find(|r| r.name == "estimate");
    assert_eq!(row.map(|r| r.state.clone()), Some(StageState::Cached));
    assert!(kept.matches.len() > 8000 && kept.matches.len() <= 20_000);
    let pair = Dataset::load(&demo_manifest())
        .unwrap()
        .load_pair(&id)
        .unwrap();
    let lib = cgenreg::pipeline::Registration::new(&s).run(&pair).unwrap();
    let pose = |m: &cgenreg::app::InspectorModel| m.estimated.map(|e| e.to_homogeneous());
    assert_eq!(pose(&kept), Some(lib.estimate.to_homogeneous()));
    assert_eq!(pose(&kept), pose(&first));
}

/// After an open: the last settings the worker sent the controls, every log line (an error
/// fails the test) and the model of the first pair once it finished.
fn settings_logs_and_result(
    handle: &WorkerHandle,
) -> (Option<RegisterParams>, Vec<String>, Box<InspectorModel>) {
    let t0 = Instant::now();
    let (mut settings, mut logs, mut done) = (None, Vec::new(), None);
    while done.is_none() && t0.elapsed() < Duration::from_secs(300) {
        for e in handle.poll() {
            match e {
                WorkerEvent::Settings(s) => settings = Some(*s),
                WorkerEvent::Log(l, t) => {
                    assert_ne!(l, LogLevel::Error, "{t}");
                    logs.push(t);
                }
                WorkerEvent::Model(m) => {
                    let st = m.current_pair.map(|i| m.pairs[i].status.clone());
                    if matches!(st, Some(PairStatus::Done) | Some(PairStatus::Failed(_))) {
                        done = Some(m);
                    }
                }
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let m = done.unwrap_or_else(|| panic!("no result; log: {logs:?}"));
    (settings, logs, m)
}

/// A manifest that names a preset opens under it in the inspector (as `gui MANIFEST` and `bench`
/// do): KITTI 07 names `outdoor`, so the worker switches to voxel 0.3 m and the KITTI criterion,
/// says so, sends the controls the new settings, and judges the first pair by them.
#[test]
fn opening_a_manifest_with_a_preset_applies_it() {
    use cgenreg::pipeline::params::Preset;
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let kitti = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/kitti07.toml");
    let worker =
        PipelineWorker::open_manifest(&demo_manifest(), RegisterParams::default()).unwrap();
    let handle = spawn_worker(Box::new(worker), None);
    open(&handle, OpenKind::Manifest, vec![kitti]);
    let (settings, logs, m) = settings_logs_and_result(&handle);
    let s = settings.expect("the worker sent the preset's settings to the controls");
    assert_eq!(Preset::of(&s), Some(Preset::Outdoor), "{s:?}");
    assert_eq!(s.voxel, 0.3);
    assert!(
        logs.iter()
            .any(|t| t.contains("outdoor") && t.contains("kitti07")),
        "{logs:?}"
    );
    // the first pair (3 m apart) registers under the KITTI criterion
    let row = &m.pairs[m.current_pair.unwrap()];
    assert_eq!(row.status, PairStatus::Done, "{logs:?}");
    assert!(row.success == Some(true), "{row:?}");
}

/// The inspector's geometry-only run goes through the stage cache like `register` and
/// `bench`: a worker writes both scans' `geo-fpfh` entries, another worker on the same cache
/// loads them and gets the same pose, and a repeat on the first worker takes the kept branch
/// from memory.
#[test]
fn the_inspectors_geometry_only_runs_use_the_fpfh_cache() {
    use cgenreg::app::model::StageState;
    let dir = tempfile::tempdir().unwrap();
    let open = || {
        let mut w = PipelineWorker::open_manifest(&demo_manifest(), params()).unwrap();
        w.set_cache(Some(cgenreg::cache::Cache::open(dir.path()).unwrap()));
        w
    };
    let fpfh = |m: &cgenreg::app::InspectorModel| -> Vec<(String, StageState)> {
        m.stages
            .iter()
            .filter(|s| s.name.starts_with("fpfh "))
            .map(|s| (s.name.clone(), s.state.clone()))
            .collect()
    };
    let mut w = open();
    let id = w.pair_ids()[0].clone();
    assert!(w.params().image.is_none());
    let a = w.run_pair(&id).unwrap();
    assert_eq!(
        fpfh(&a),
        [
            ("fpfh source".to_string(), StageState::Done),
            ("fpfh target".to_string(), StageState::Done)
        ]
    );
    assert_eq!(
        std::fs::read_dir(dir.path().join("geo-fpfh"))
            .unwrap()
            .count(),
        2
    );
    let b = open().run_pair(&id).unwrap();
    assert_eq!(
        fpfh(&b),
        [
            ("fpfh source".to_string(), StageState::Cached),
            ("fpfh target".to_string(), StageState::Cached)
        ]
    );
    assert_eq!(b.estimated, a.estimated);
    let c = w.run_pair(&id).unwrap();
    assert_eq!(
        fpfh(&c),
        [(
            "fpfh source + target (in memory)".to_string(),
            StageState::Cached
        )]
    );
    assert_eq!(c.estimated, a.estimated);
}

/// A manifest's `geo_features` names the descriptor its pairs run with; another value is an
/// error naming the file, the field and the names it takes.
#[test]
fn a_manifests_geo_features_field_is_read_and_checked() {
    use cgenreg::features::{spinnet::Protocol, DescriptorName};
    let demo_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo");
    let text = std::fs::read_to_string(demo_dir.join("demo.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let with = |line: &str, name: &str| {
        let m = dir.path().join(name);
        let t = text.replace(
            "root = \".\"",
            &format!("{line}\nroot = {:?}", demo_dir.display().to_string()),
        );
        std::fs::write(&m, t).unwrap();
        m
    };
    let ok = with("geo_features = \"spinnet-kitti\"", "kitti.toml");
    assert_eq!(
        Dataset::load(&ok).unwrap().geo_features,
        Some(DescriptorName::Spinnet(Protocol::Kitti))
    );
    assert_eq!(Dataset::load(&demo_manifest()).unwrap().geo_features, None);
    let bad = with("geo_features = \"shot\"", "bad.toml");
    let err = Dataset::load(&bad).unwrap_err().to_string();
    assert!(
        err.contains("bad.toml")
            && err.contains("geo_features")
            && err.contains("spinnet-3dmatch")
            && err.contains("shot"),
        "{err}"
    );
}

/// A manifest's `scene_prompt` is its scene-specific prompt: opening it in the inspector with
/// the scene-specific prompt on switches the prompt to that description (the controls follow,
/// the log says so) and every model carries it for the "Scene-specific" button; an empty one
/// is an error naming the field.
#[test]
fn a_manifests_scene_prompt_is_the_scene_specific_prompt() {
    use cgenreg::wfm::PromptPreset;
    let demo_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo");
    let text = std::fs::read_to_string(demo_dir.join("demo.toml")).unwrap();
    let scene = "a small synthetic room with two boxes on a floor";
    let dir = tempfile::tempdir().unwrap();
    let with_scene = |scene_line: &str| {
        text.replace(
            "root = \".\"",
            &format!("{scene_line}\nroot = {:?}", demo_dir.display().to_string()),
        )
    };
    let m = dir.path().join("scene.toml");
    std::fs::write(&m, with_scene(&format!("scene_prompt = {scene:?}"))).unwrap();
    let empty = dir.path().join("empty.toml");
    std::fs::write(&empty, with_scene("scene_prompt = \"  \"")).unwrap();
    let err = Dataset::load(&empty).unwrap_err().to_string();
    assert!(
        err.contains("scene_prompt") && err.contains("empty.toml"),
        "{err}"
    );
    assert_eq!(
        Dataset::load(&m).unwrap().scene_prompt.as_deref(),
        Some(scene)
    );

    let p = common::demo_params(cgenreg::pipeline::WfmSpec::Builtin);
    assert_eq!(
        p.image.as_ref().unwrap().prompt.scene,
        PromptPreset::SceneSpecific.default_scene()
    );
    let worker = PipelineWorker::open_manifest(&demo_manifest(), p).unwrap();
    let handle = spawn_worker(Box::new(worker), None);
    open(&handle, OpenKind::Manifest, vec![m]);
    let (settings, logs, m) = settings_logs_and_result(&handle);
    let s = settings.expect("the worker sent the new prompt to the controls");
    assert_eq!(s.image.as_ref().unwrap().prompt.scene, scene);
    assert_eq!(m.scene_prompt.as_deref(), Some(scene));
    assert!(
        logs.iter().any(|t| t.contains("scene-specific prompt")),
        "{logs:?}"
    );
}
