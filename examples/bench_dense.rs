//! Benchmark of the per-image VFMs (not a timed test): time per image at 640x480 and 960x704,
//! K = 4 views per side (8 images at 960x704, descriptors sampled at 5,000 pixels each), and the
//! process's peak resident memory, on native ONNX Runtime and on tract. Each (backend, model) runs
//! in its own child process: the backend is chosen once per process, and the peak RSS is then
//! that model's alone.
//!
//! `CGENREG_DATA=../shared/data cargo run --example bench_dense` (dev profile; dependencies at
//! opt-level 2, the crate at 1). Frames: real 7-Scenes redkitchen colour frames (resized to
//! 960x704 for the larger size and for K = 4), decoded before timing, as the pipeline's cached
//! generated frames would be.

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use cgenreg::vfm::dense::{DenseKind, DenseModel};
use cgenreg::vfm::{default_model_path, PerImageModel};
use std::time::Instant;

fn frames(w: u32, h: u32, n: usize) -> Vec<image::RgbImage> {
    let seq = cgenreg::data_root()
        .map(|r| r.join("7scenes-redkitchen-rgbd"))
        .and_then(|d| cgenreg::dataset::rgbd_sequence::RgbdSequence::open(&d).ok())
        .expect("redkitchen frames (set CGENREG_DATA)");
    (0..n)
        .map(|i| {
            let p = seq.frame(i * 50).unwrap().color.clone().unwrap();
            let img = image::open(p).unwrap().to_rgb8();
            if img.dimensions() == (w, h) {
                img
            } else {
                image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle)
            }
        })
        .collect()
}

/// 5,000 pixels spread over the image (what lifting links for ~5k keypoints).
fn pixels(w: u32, h: u32) -> Vec<(f32, f32)> {
    (0..5000u32)
        .map(|i| (((i * 7919) % w) as f32, ((i * 104729) % h) as f32))
        .collect()
}

fn peak_rss_mb() -> f64 {
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    u.ru_maxrss as f64 / 1024.0
}

enum Model {
    Dense(DenseModel),
    Xfeat(cgenreg::vfm::xfeat::XFeat),
}

impl Model {
    fn run(&self, img: &image::RgbImage, px: &[(f32, f32)]) {
        let d = match self {
            Model::Dense(m) => m.describe_at(img, px),
            Model::Xfeat(m) => m.describe_at(img, px),
        }
        .expect("describe");
        assert_eq!(d.data.len(), px.len() * d.dim);
    }
}

fn child(model: &str, reps: usize, k4: bool) {
    let t = Instant::now();
    let m = match model {
        "disk" => Model::Dense(
            DenseModel::load(&default_model_path("disk.onnx"), DenseKind::Disk).unwrap(),
        ),
        "alike-t" | "alike-n" => Model::Dense(
            DenseModel::load(
                &default_model_path(&format!("{model}.onnx")),
                DenseKind::Alike,
            )
            .unwrap(),
        ),
        "xfeat" => Model::Xfeat(cgenreg::vfm::xfeat::XFeat::load_default().unwrap()),
        _ => panic!("unknown model {model}"),
    };
    let load_s = t.elapsed().as_secs_f64();
    let mut cells = vec![format!("{load_s:.1} s")];
    for (w, h) in [(640u32, 480u32), (960, 704)] {
        let imgs = frames(w, h, reps + 1);
        let px = pixels(w, h);
        m.run(&imgs[0], &px); // warm-up (tract plans the graph here)
        let mut times: Vec<f64> = imgs[1..]
            .iter()
            .map(|img| {
                let t = Instant::now();
                m.run(img, &px);
                t.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(|a, b| a.total_cmp(b));
        cells.push(format!("{:.0} ms", 1e3 * times[times.len() / 2]));
    }
    if k4 {
        let imgs = frames(960, 704, 8);
        let px = pixels(960, 704);
        let t = Instant::now();
        for img in &imgs {
            m.run(img, &px);
        }
        cells.push(format!("{:.2} s", t.elapsed().as_secs_f64()));
    } else {
        cells.push("not run".into());
    }
    cells.push(format!("{:.0} MB", peak_rss_mb()));
    println!(
        "ROW | {model} | {} | {} |",
        cgenreg::vfm::backend_name(),
        cells.join(" | ")
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() >= 4 && args[1] == "--child" {
        return child(
            &args[2],
            args[3].parse().unwrap(),
            args.get(4).is_some_and(|a| a == "k4"),
        );
    }
    println!(
        "| model | backend | load | 640x480 / image | 960x704 / image | K = 4 per side (8 x 960x704) | peak RSS |"
    );
    println!("|---|---|---|---|---|---|---|");
    // (model, backend, reps per size, K = 4 run): tract on DISK is slow, so one image per size.
    let plan: &[(&str, &str, usize, bool)] = &[
        ("xfeat", "native", 3, true),
        ("alike-t", "native", 3, true),
        ("alike-n", "native", 3, true),
        ("disk", "native", 3, true),
        ("xfeat", "tract", 2, true),
        ("alike-t", "tract", 2, true),
        ("alike-n", "tract", 1, false),
        ("disk", "tract", 1, false),
    ];
    let only = std::env::var("BENCH_ONLY").unwrap_or_default();
    for &(model, backend, reps, k4) in plan {
        if !only.is_empty() && !only.split(',').any(|o| o == model || o == backend) {
            continue;
        }
        let mut cmd = std::process::Command::new(std::env::current_exe().unwrap());
        cmd.args(["--child", model, &reps.to_string()]);
        if k4 {
            cmd.arg("k4");
        }
        let out = cmd.env("CGENREG_ORT_BACKEND", backend).output().unwrap();
        let s = String::from_utf8_lossy(&out.stdout);
        match s.lines().find(|l| l.starts_with("ROW ")) {
            Some(l) => println!("{}", &l[4..]),
            None => println!(
                "| {model} | {backend} | failed: {} |",
                String::from_utf8_lossy(&out.stderr)
                    .lines()
                    .last()
                    .unwrap_or("")
            ),
        }
    }
}
