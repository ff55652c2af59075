//! Frame time of the inspector's 3D panel rendered headless (surfaceless EGL; Mesa llvmpipe
//! on machines without a GPU), with 100k and 300k points per cloud.
//!
//! Run: `cargo bench --bench gui`. Prints median / mean / p90 per configuration.

use std::time::Instant;

use cgenreg::app::headless::HeadlessRenderer;
use cgenreg::app::{InspectorModel, Panel};

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

fn run(
    label: &str,
    model: InspectorModel,
    panel: Panel,
    size: (u32, u32),
    frames: usize,
) -> Result<(), String> {
    let mut r = HeadlessRenderer::new(model, size)?;
    r.app.ui_state.tab = panel;
    if std::env::var_os("GUI_BENCH_NOPOINTS").is_some() {
        let p = r.app.view3d_prefs_mut();
        p.show_target = false;
        p.show_estimated = false;
    }
    if let Ok(s) = std::env::var("GUI_BENCH_POINT_SIZE") {
        r.app.view3d_prefs_mut().point_size = s.parse().unwrap_or(2.0);
    }
    for _ in 0..5 {
        r.app.orbit_3d(3.0, 0.0);
        r.frame(false)?;
    }
    let mut times = Vec::with_capacity(frames);
    let cpu0 = cpu_ms();
    for _ in 0..frames {
        r.app.orbit_3d(3.0, 0.0);
        let t = Instant::now();
        r.frame(false)?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let cpu = (cpu_ms() - cpu0) / frames as f64;
    let (med, mean, p90) = stats(times);
    println!(
        "{label:<32} {}x{}  median {med:6.1} ms  mean {mean:6.1} ms  p90 {p90:6.1} ms  cpu {cpu:6.1} ms/frame  ({})",
        size.0, size.1, r.gl.renderer
    );
    Ok(())
}

fn main() {
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
        )?;
        for n in [100_000usize, 300_000] {
            let t = Instant::now();
            let model = InspectorModel::demo_sized(n);
            eprintln!(
                "built demo with {n} points per cloud in {:.0} ms",
                t.elapsed().as_secs_f64() * 1e3
            );
            run(
                &format!("3D panel, {}k points/cloud", n / 1000),
                model.clone(),
                Panel::View3d,
                size,
                frames,
            )?;
            run(
                &format!("views + 3D, {}k points/cloud", n / 1000),
                model,
                Panel::Views,
                size,
                frames,
            )?;
        }
        Ok(())
    })();
    if let Err(e) = result {
        eprintln!("gui bench skipped: {e}");
    }
}
