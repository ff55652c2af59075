//! Frame time of the inspector's 3D panel rendered headless (surfaceless EGL; Mesa llvmpipe
//! on machines without a GPU), with 100k and 300k points per cloud; and the latency from a
//! temperature change to the updated model, to the first 3D frame drawn with it and to the
//! complete 3D view (still views refine over frames, as in the inspector) on real 3DMatch
//! redkitchen pairs whose stages are cached (needs `$CGENREG_DATA`).
//!
//! Run: `cargo bench --bench gui`. Prints median / mean / p90 per configuration.
//! `GUI_BENCH_ONLY=latency` (or `frames`, or `splat`: the CPU splatting kernel alone) runs one
//! part.

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::time::Instant;

use cgenreg::app::headless::HeadlessRenderer;
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{spawn_worker, Command, InspectorModel, Panel, WorkerEvent};
use cgenreg::fusion::select::Selection;
use cgenreg::pipeline::{ImageBranchParams, RegisterParams, WfmSpec};

/// CPU time of the whole process (all threads, llvmpipe's included), ms: unlike wall time it
/// barely moves when other processes compete for the cores.
fn cpu_ms() -> f64 {
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 * 1e3 + v.tv_usec as f64 / 1e3;
    t(u.ru_utime) + t(u.ru_stime)
}

fn stats(mut v: Vec<f64>) -> (f64, f64, f64) {
    v.sort_by(|a, b| a.total_cmp(b));
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (v[v.len() / 2], mean, v[(v.len() * 9) / 10])
}

/// How a run's frames are drawn.
#[derive(Clone, Copy, PartialEq)]
enum Motion {
    /// The camera moves every frame (the moving point budget applies).
    Orbit,
    /// The camera stops after the warm-up; its first frame draws every point not yet drawn
    /// (the headless mode), later frames of the unchanged view only composite.
    StillComplete,
    /// The camera stops after the warm-up; the view is refined over frames, then kept (the
    /// interactive default).
    StillProgressive,
}

fn run(
    label: &str,
    model: InspectorModel,
    panel: Panel,
    size: (u32, u32),
    frames: usize,
    motion: Motion,
) -> Result<(), String> {
    let mut r = HeadlessRenderer::new(model, size)?;
    r.app.ui_state.tab = panel;
    r.app
        .set_complete_3d_frames(motion == Motion::StillComplete);
    if std::env::var_os("GUI_BENCH_NOPOINTS").is_some() {
        let p = r.app.view3d_prefs_mut();
        p.show_target = false;
        p.show_estimated = false;
    }
    if let Ok(s) = std::env::var("GUI_BENCH_POINT_SIZE") {
        r.app.view3d_prefs_mut().point_size = s.parse().unwrap_or(2.0);
    }
    // GUI_BENCH_DEPTH_CUE=none|normals|edl (default: the view's default)
    if let Ok(s) = std::env::var("GUI_BENCH_DEPTH_CUE") {
        use cgenreg::app::render3d::DepthCue;
        r.app.view3d_prefs_mut().depth_cue = match s.as_str() {
            "none" => DepthCue::None,
            "normals" => DepthCue::Normals,
            "edl" => DepthCue::Edl,
            _ => {
                return Err(format!(
                    "GUI_BENCH_DEPTH_CUE={s}: expected none, normals or edl"
                ))
            }
        };
    }
    r.app.view3d_prefs_mut().rasterizer = rasterizer()?;
    let cue = r.app.view3d_prefs_mut().depth_cue.label();
    for _ in 0..5 {
        r.app.orbit_3d(3.0, 0.0);
        r.frame(false)?;
    }
    let mut times = Vec::with_capacity(frames);
    // still views: frames from the camera's stop until every point is drawn
    let mut to_complete: Option<(usize, f64)> = None;
    let cpu0 = cpu_ms();
    for i in 0..frames {
        if motion == Motion::Orbit {
            r.app.orbit_3d(3.0, 0.0);
        }
        let t = Instant::now();
        r.frame(false)?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
        if motion != Motion::Orbit && to_complete.is_none() && !r.app.view3d_refining() {
            to_complete = Some((i + 1, times.iter().sum()));
        }
    }
    let cpu = (cpu_ms() - cpu0) / frames as f64;
    let first: Vec<String> = times.iter().take(3).map(|t| format!("{t:.1}")).collect();
    let max = times.iter().cloned().fold(0.0f64, f64::max);
    let (med, mean, p90) = stats(times);
    let complete = match to_complete {
        Some((n, ms)) => format!("; complete after {n} frame(s), {ms:.1} ms"),
        None if motion == Motion::Orbit => format!(
            "; drawing {} points per cloud while moving (adapted)",
            r.app.view3d_moving_budget()
        ),
        None => "; NOT complete".to_string(),
    };
    println!(
        "{label:<44} {}x{}  median {med:6.1} ms  mean {mean:6.1} ms  p90 {p90:6.1} ms  max {max:6.1} ms  cpu {cpu:6.1} ms/frame  first [{}] ms{complete}  (depth cue: {cue}; points: {}; {})",
        size.0,
        size.1,
        first.join(", "),
        r.app.view3d_prefs_mut().rasterizer.label(),
        r.gl.renderer
    );
    Ok(())
}

/// GUI_BENCH_RASTERIZER=auto|gl|cpu (default auto: CPU splatting under llvmpipe).
fn rasterizer() -> Result<cgenreg::app::render3d::Rasterizer, String> {
    use cgenreg::app::render3d::Rasterizer;
    match std::env::var("GUI_BENCH_RASTERIZER").as_deref() {
        Err(_) | Ok("auto") => Ok(Rasterizer::Auto),
        Ok("gl") => Ok(Rasterizer::Gl),
        Ok("cpu") => Ok(Rasterizer::Cpu),
        Ok(s) => Err(format!(
            "GUI_BENCH_RASTERIZER={s}: expected auto, gl or cpu"
        )),
    }
}

/// Temperature change -> updated model, through the worker thread as the UI sees it, then one
/// headless frame of the 3D panel with the new model.
fn latency(
    label: &str,
    manifest: &str,
    pair: Option<&str>,
    params: RegisterParams,
    reps: usize,
) -> Result<(), String> {
    let root = env!("CARGO_MANIFEST_DIR");
    let path = std::path::Path::new(root).join(manifest);
    let mut worker = PipelineWorker::open_manifest(&path, params).map_err(|e| e.to_string())?;
    let id = match pair {
        Some(p) => p.to_string(),
        None => worker.pair_ids().first().cloned().ok_or("no pairs")?,
    };
    // cold in memory: the first run fills the stage cache (a no-op when already warm)
    let t = Instant::now();
    let m = worker.run_pair(&id).map_err(|e| e.to_string())?;
    let first = t.elapsed().as_secs_f64() * 1e3;
    let cached = m
        .stages
        .iter()
        .filter(|s| s.state == cgenreg::app::model::StageState::Cached)
        .count();
    let views = m.source_views.len() + m.target_views.len();
    let mut settings = worker.params().clone();
    let mut r = HeadlessRenderer::new(m, (1280, 800))?;
    r.app.ui_state.tab = Panel::View3d;
    r.app.view3d_prefs_mut().rasterizer = rasterizer()?;
    // as the inspector draws: a still view refined over frames (its first frame is partial
    // when a cloud has more than view3d::REFINE_POINTS_PER_FRAME points)
    r.app.set_complete_3d_frames(false);
    r.frame(false)?;
    while r.app.view3d_refining() {
        r.frame(false)?;
    }
    let h = spawn_worker(Box::new(worker), None);
    let (mut to_model, mut to_frame, mut cpu_model) = (Vec::new(), Vec::new(), Vec::new());
    let (mut to_complete, mut frames_to_complete) = (Vec::new(), Vec::new());
    let mut set_model = Vec::new();
    let mut to_refined = Vec::new();
    let mut stages = String::new();
    for i in 0..reps {
        let tau = if i % 2 == 0 { 0.12 } else { 0.1 };
        *settings.fusion.calibration_geo.tau_mut() = tau;
        *settings.fusion.calibration_img.tau_mut() = tau;
        let t = Instant::now();
        let c0 = cpu_ms();
        h.send(Command::ApplySettings(settings.clone()));
        let model = loop {
            if let Some(m) = h.poll().into_iter().find_map(|e| match e {
                WorkerEvent::Model(m) => Some(m),
                _ => None,
            }) {
                break m;
            }
            if t.elapsed().as_secs() > 120 {
                return Err("no model within 120 s".into());
            }
            std::thread::sleep(std::time::Duration::from_micros(200));
        };
        to_model.push(t.elapsed().as_secs_f64() * 1e3);
        cpu_model.push(cpu_ms() - c0);
        // a preview (the visibility rule's fast answer) is drawn first; the refined model
        // follows when the worker is idle
        let preview = model.preview_note.is_some();
        if preview {
            let refined = loop {
                if let Some(m) = h.poll().into_iter().find_map(|e| match e {
                    WorkerEvent::Model(m) if m.preview_note.is_none() => Some(m),
                    _ => None,
                }) {
                    break m;
                }
                if t.elapsed().as_secs() > 120 {
                    return Err("no refined model within 120 s".into());
                }
                std::thread::sleep(std::time::Duration::from_micros(200));
            };
            to_refined.push(t.elapsed().as_secs_f64() * 1e3);
            drop(refined);
        }
        stages = model
            .stages
            .iter()
            .map(|s| {
                let st = match s.state {
                    cgenreg::app::model::StageState::Cached => "cached",
                    cgenreg::app::model::StageState::Done => "computed",
                    _ => "other",
                };
                format!("{} {st} {:.0} ms", s.name, s.time_ms.unwrap_or(0.0))
            })
            .collect::<Vec<_>>()
            .join(", ");
        let t_set = Instant::now();
        r.app.set_model(*model);
        set_model.push(t_set.elapsed().as_secs_f64() * 1e3);
        r.frame(false)?;
        // the first frame drawn with the change (the preview's, when there is one: its time to
        // the frame is its model's time plus one frame, measured apart from the refinement)
        to_frame.push(if preview {
            to_model[to_model.len() - 1] + (t_set.elapsed().as_secs_f64() * 1e3)
        } else {
            t.elapsed().as_secs_f64() * 1e3
        });
        let mut frames = 1;
        while r.app.view3d_refining() && frames < 20 {
            r.frame(false)?;
            frames += 1;
        }
        to_complete.push(t.elapsed().as_secs_f64() * 1e3);
        frames_to_complete.push(frames as f64);
    }
    let (m1, a1, p1) = stats(to_model);
    let (m2, a2, p2) = stats(to_frame);
    let (m3, _, p3) = stats(to_complete);
    let (f3, _, _) = stats(frames_to_complete);
    let (c1, _, _) = stats(cpu_model);
    let (s1, _, _) = stats(set_model);
    let refined = if to_refined.is_empty() {
        String::new()
    } else {
        let (m, a, p) = stats(to_refined);
        format!(" | preview first; -> refined model: median {m:6.1} mean {a:6.1} p90 {p:6.1} ms")
    };
    // CPU: all threads of the process from the command to the model (it moves less than wall
    // time when other processes share the cores)
    println!(
        "{label:<44} first run {first:7.0} ms ({cached} stages cached, {views} views) | tau change -> model: median {m1:6.1} mean {a1:6.1} p90 {p1:6.1} ms (CPU median {c1:6.1} ms) | -> first 3D frame: median {m2:6.1} mean {a2:6.1} p90 {p2:6.1} ms (App::set_model median {s1:.1} ms) | -> complete 3D view: median {m3:6.1} p90 {p3:6.1} ms ({f3:.0} frames){refined}"
    );
    eprintln!("  last stages: {stages}");
    Ok(())
}

fn latency_part(reps: usize) {
    if cgenreg::data_root().is_none() {
        eprintln!("latency bench skipped: no $CGENREG_DATA");
        return;
    }
    let geo = RegisterParams {
        fusion: cgenreg::fusion::FusionParams {
            selection: Selection::RowNn,
            mode: cgenreg::fusion::FusionMode::GeometryOnly,
            ..Default::default()
        },
        ..Default::default()
    };
    let oracle = RegisterParams {
        image: Some(ImageBranchParams {
            backend: WfmSpec::Oracle,
            ..Default::default()
        }),
        ..Default::default()
    };
    let visibility = RegisterParams {
        fusion: cgenreg::fusion::FusionParams {
            mode: cgenreg::fusion::FusionMode::Visibility,
            ..oracle.fusion
        },
        ..oracle.clone()
    };
    let runs: [(&str, &str, Option<&str>, RegisterParams); 4] = [
        (
            "staged 3DMatch, geometry only (FPFH, nn)",
            "assets/manifests/redkitchen-staged.toml",
            None,
            geo.clone(),
        ),
        (
            "rgbd 0-1, geometry only (FPFH, nn)",
            "assets/manifests/redkitchen-rgbd.toml",
            Some("redkitchen-rgbd/0-1"),
            geo,
        ),
        (
            "rgbd 0-1, oracle + XFeat, Noisy-AND (mutual)",
            "assets/manifests/redkitchen-rgbd.toml",
            Some("redkitchen-rgbd/0-1"),
            oracle,
        ),
        (
            "rgbd 0-1, oracle + XFeat, visibility (default)",
            "assets/manifests/redkitchen-rgbd.toml",
            Some("redkitchen-rgbd/0-1"),
            visibility,
        ),
    ];
    // GUI_BENCH_LATENCY=substring: only the configurations whose label holds it
    let only = std::env::var("GUI_BENCH_LATENCY").unwrap_or_default();
    for (label, manifest, pair, params) in runs {
        if !label.contains(only.as_str()) {
            continue;
        }
        if let Err(e) = latency(label, manifest, pair, params, reps) {
            eprintln!("{label}: skipped: {e}");
        }
    }
}

/// The CPU splatting kernel alone (`render3d::SplatImage`): both clouds of the 300k demo
/// into a 1000 x 700 image (about the 3D panel in a 1280 x 800 window) seen from its framing
/// camera, on 1 thread and on every core; no GL.
fn splat_kernel() {
    use cgenreg::app::render3d::{SplatCloud, SplatImage};
    use cgenreg::app::view3d::SceneCamera;
    let model = InspectorModel::demo_sized(300_000);
    let Some((lo, hi)) = model.bounds() else {
        return;
    };
    let mut cam = SceneCamera::framing(lo, hi);
    let vp = cam.view_projection(1000.0, 700.0);
    let mvp: [f32; 16] = vp.as_slice().try_into().expect("4x4");
    let identity: [f32; 16] = nalgebra::Matrix4::<f32>::identity()
        .as_slice()
        .try_into()
        .expect("4x4");
    let colors = vec![[200u8, 180, 40, 255]; 300_000];
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for threads in [1, cores] {
        let mut img = SplatImage::new(1000, 700);
        let mut times = Vec::new();
        for _ in 0..30 {
            let t = Instant::now();
            img.clear([0.0, 0.0, 0.0, 1.0]);
            for cloud in [&model.source, &model.target] {
                let c = SplatCloud {
                    positions: cloud,
                    colors: &colors,
                    normals: None,
                    mvp,
                    model: identity,
                    tint: [1.0; 4],
                    eye: [0.0; 3],
                    point_size: 2.0,
                };
                img.splat(&c, (0, cloud.len()), threads);
            }
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let (med, mean, p90) = stats(times);
        println!(
            "CPU splat kernel, 2 x 300k points, 1000x700, {threads} thread(s): median {med:.1} ms  mean {mean:.1} ms  p90 {p90:.1} ms (clear included)"
        );
    }
}

fn main() {
    let only = std::env::var("GUI_BENCH_ONLY").unwrap_or_default();
    if only != "frames" {
        let reps = std::env::var("GUI_BENCH_REPS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(10);
        latency_part(reps);
    }
    if only == "latency" {
        return;
    }
    splat_kernel();
    if only == "splat" {
        return;
    }
    let size = (1280, 800);
    let frames = std::env::var("GUI_BENCH_FRAMES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(40);
    let result = (|| -> Result<(), String> {
        run(
            "stages panel (no 3D)",
            InspectorModel::demo(),
            Panel::Stages,
            size,
            frames,
            Motion::StillComplete,
        )?;
        for n in [100_000usize, 300_000] {
            let t = Instant::now();
            let model = InspectorModel::demo_sized(n);
            eprintln!(
                "built demo with {n} points per cloud in {:.0} ms",
                t.elapsed().as_secs_f64() * 1e3
            );
            let k = n / 1000;
            for (what, panel, motion) in [
                ("3D panel, orbiting", Panel::View3d, Motion::Orbit),
                (
                    "3D panel, still, one frame",
                    Panel::View3d,
                    Motion::StillComplete,
                ),
                (
                    "3D panel, still, progressive",
                    Panel::View3d,
                    Motion::StillProgressive,
                ),
                ("views + 3D, orbiting", Panel::Views, Motion::Orbit),
            ] {
                let label = format!("{what}, {k}k points/cloud");
                run(&label, model.clone(), panel, size, frames, motion)?;
            }
        }
        Ok(())
    })();
    if let Err(e) = result {
        eprintln!("gui bench skipped: {e}");
    }
}
