//! VFM benchmarks: XFeat on 8 frames at 960x704 (native ONNX Runtime and the tract fallback, each
//! in its own child process because the backend is chosen once per process), and lifting for
//! K = 4 views against ~5k geometric points.
//!
//! `cargo bench --no-default-features --features onnx --bench vfm`
//! Uses the real 7-Scenes redkitchen frames when `CGENREG_DATA` (or ../shared/data) has them,
//! synthetic frames otherwise.

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use cgenreg::camera::DepthView;
use cgenreg::io::depth_png::{read_depth_png, DepthImage};
use cgenreg::vfm::lift::lift_views;
use nalgebra::{Isometry3, Point3};
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

#[cfg_attr(not(feature = "onnx"), allow(dead_code))]
fn frames_960x704() -> Vec<image::RgbImage> {
    let seq = cgenreg::data_root()
        .map(|r| r.join("7scenes-redkitchen-rgbd"))
        .and_then(|d| cgenreg::dataset::rgbd_sequence::RgbdSequence::open(&d).ok());
    (0..8)
        .map(|i| {
            let real = seq
                .as_ref()
                .and_then(|s| s.frame(i * 50))
                .and_then(|f| f.color.clone());
            match real.and_then(|p| image::open(p).ok()) {
                Some(img) => image::imageops::resize(
                    &img.to_rgb8(),
                    960,
                    704,
                    image::imageops::FilterType::Triangle,
                ),
                None => image::RgbImage::from_fn(960, 704, |x, y| {
                    let v = ((x * 7 + y * 3 + i as u32 * 31) % 255) as u8;
                    image::Rgb([v, v / 2, 255 - v])
                }),
            }
        })
        .collect()
}

#[cfg(feature = "onnx")]
fn bench_xfeat() {
    use cgenreg::vfm::PerImageModel;
    let model = match cgenreg::vfm::xfeat::XFeat::load_default() {
        Ok(m) => m,
        Err(e) => {
            println!("xfeat: skipped ({e})");
            return;
        }
    };
    let imgs = frames_960x704();
    let _ = model.describe(&imgs[0]);
    let mut runs = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        for img in &imgs {
            let d = model.describe(img).expect("describe");
            assert_eq!(d.dim, 64);
        }
        runs.push(t.elapsed().as_secs_f64());
    }
    let m = median(runs);
    println!(
        "xfeat 8 x 960x704 [{}]: {:.3} s total, {:.1} ms/image (median of 3)",
        cgenreg::vfm::backend_name(),
        m,
        m * 1000.0 / 8.0
    );
}

fn lift_inputs() -> (
    Vec<DepthImage>,
    Vec<Isometry3<f64>>,
    cgenreg::camera::Intrinsics,
) {
    let seq = cgenreg::data_root()
        .map(|r| r.join("7scenes-redkitchen-rgbd"))
        .and_then(|d| cgenreg::dataset::rgbd_sequence::RgbdSequence::open(&d).ok());
    if let Some(seq) = seq {
        let k = seq.intrinsics().expect("intrinsics");
        let first = seq.world_from_camera(0).expect("pose");
        let ids = [0usize, 11, 22, 33];
        let d = ids
            .iter()
            .map(|&i| read_depth_png(&seq.frame(i).unwrap().depth).unwrap())
            .collect();
        let p = ids
            .iter()
            .map(|&i| first.inverse() * seq.world_from_camera(i).unwrap())
            .collect();
        return (d, p, k);
    }
    let k = cgenreg::camera::Intrinsics {
        fx: 585.0,
        fy: 585.0,
        cx: 320.0,
        cy: 240.0,
        width: 640,
        height: 480,
    };
    let d = (0..4)
        .map(|s| DepthImage {
            width: 640,
            height: 480,
            data: (0..640 * 480)
                .map(|i| (1500 + (i % 640) + s * 10) as u16)
                .collect(),
        })
        .collect();
    let p = (0..4)
        .map(|i| Isometry3::translation(0.05 * i as f64, 0.0, 0.0))
        .collect();
    (d, p, k)
}

fn bench_lift() {
    let (depths, poses, k) = lift_inputs();
    let cam = cgenreg::camera::CameraModel::Pinhole(k);
    let views: Vec<DepthView> = depths
        .iter()
        .zip(&poses)
        .map(|(d, p)| DepthView {
            depth: d,
            scan_from_camera: *p,
            camera: &cam,
        })
        .collect();
    // ~5k geometric points: every 61st valid pixel of view 0, jittered by up to 3 cm.
    let d0 = &depths[0];
    let mut geo = Vec::new();
    for (i, &raw) in d0.data.iter().enumerate().step_by(61) {
        if raw == 0 || raw == u16::MAX {
            continue;
        }
        let (u, v) = ((i as u32 % d0.width) as f64, (i as u32 / d0.width) as f64);
        let p = poses[0] * k.backproject(u, v, raw as f64 / 1000.0);
        let j = ((i % 7) as f64 - 3.0) * 0.01;
        geo.push(Point3::new((p.x + j) as f32, (p.y - j) as f32, p.z as f32));
    }
    let _ = lift_views(&views, &geo, 0.05, (960, 704), 5.0);
    let mut runs = Vec::new();
    let mut linked = 0;
    for _ in 0..5 {
        let t = Instant::now();
        let r = lift_views(&views, &geo, 0.05, (960, 704), 5.0).expect("lift");
        runs.push(t.elapsed().as_secs_f64());
        linked = r.iter().filter(|x| x.is_some()).count();
    }
    println!(
        "lift K=4 views 640x480 -> 960x704, {} geo points ({} linked): {:.1} ms (median of 5, {} threads)",
        geo.len(),
        linked,
        median(runs) * 1000.0,
        rayon::current_num_threads()
    );
}

fn main() {
    #[cfg_attr(not(feature = "onnx"), allow(unused_variables))]
    let args: Vec<String> = std::env::args().skip(1).collect();
    #[cfg(feature = "onnx")]
    {
        if std::env::var("CGENREG_ORT_BACKEND").is_err() {
            // One child per backend: ort's backend is fixed per process.
            let exe = std::env::current_exe().expect("current exe");
            let native = !cgenreg::onnx::native_library_candidates().is_empty();
            for b in ["native", "tract"] {
                if b == "native" && !native {
                    println!("xfeat native: skipped (no ONNX Runtime library found)");
                    continue;
                }
                let st = std::process::Command::new(&exe)
                    .args(&args)
                    .env("CGENREG_ORT_BACKEND", b)
                    .env("CGENREG_BENCH_XFEAT_ONLY", "1")
                    .status()
                    .expect("child");
                if !st.success() {
                    println!("xfeat {b}: child failed ({st})");
                }
            }
        } else {
            bench_xfeat();
        }
        if std::env::var("CGENREG_BENCH_XFEAT_ONLY").is_ok() {
            return;
        }
    }
    bench_lift();
}
