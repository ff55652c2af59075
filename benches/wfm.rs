//! Timings of the generated-RGB branch up to the generated frames, on the staged redkitchen
//! data: `cargo bench --no-default-features --bench wfm` (needs CGENREG_DATA or ../shared/data).

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use cgenreg::wfm::backend::WfmBackend;
use std::time::Instant;

fn time<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let r = f();
    println!("{what:<55} {:>8.3} s", t.elapsed().as_secs_f64());
    r
}

fn main() {
    let Some(root) = cgenreg::data_root() else {
        println!("skipping: no data root (set CGENREG_DATA)");
        return;
    };
    let seq = root.join("7scenes-redkitchen-rgbd");
    let depth = |i: usize| seq.join(format!("frame-{i:06}.depth.png"));
    let src: Vec<_> = (0..50).map(depth).collect();
    let tgt: Vec<_> = (50..100).map(depth).collect();
    println!("threads: {}", rayon::current_num_threads());
    let video = time("depth video: read+encode 100 PNG frames (§1.2)", || {
        cgenreg::wfm::depth_video::pair_video_from_files(&src, &tgt).unwrap()
    });
    let dir = tempfile::tempdir().unwrap();
    let mp4 = dir.path().join("depth.mp4");
    time("write H.264 mp4, 100 frames 640x480", || {
        cgenreg::wfm::video::write_mp4_h264(&mp4, &video, 30).unwrap()
    });
    time("read H.264 mp4, 100 frames 640x480", || {
        cgenreg::wfm::video::read_mp4_frames(&mp4).unwrap()
    });
    let req = cgenreg::wfm::backend::GenerateRequest {
        pair_id: "redkitchen/0-1".into(),
        depth_video: video,
        depth_video_path: Some(mp4),
        prompt: cgenreg::wfm::Prompt::from_preset(cgenreg::wfm::PromptPreset::General),
        seed: 1,
        source_color: None,
        target_color: None,
    };
    let g = time("builtin-depthshade-v1: 100 frames at 960x704", || {
        cgenreg::wfm::builtin::DepthShadeBackend::default()
            .generate(&req)
            .unwrap()
    });
    let big = dir.path().join("gen.mp4");
    time("write H.264 mp4, 100 frames 960x704", || {
        cgenreg::wfm::video::write_mp4_h264(&big, &g.frames, 30).unwrap()
    });
    time("read H.264 mp4, 100 frames 960x704", || {
        cgenreg::wfm::video::read_mp4_frames(&big).unwrap()
    });
    // Back-project frame 0 to a cloud and re-render it (the point-cloud-only path).
    let d0 = cgenreg::io::depth_png::read_depth_png(&depth(0)).unwrap();
    let k = cgenreg::camera::Intrinsics {
        fx: 585.0,
        fy: 585.0,
        cx: 320.0,
        cy: 240.0,
        width: 640,
        height: 480,
    };
    let mut pts = Vec::new();
    for v in 0..480 {
        for u in 0..640 {
            if let Some(z) = d0.meters(u, v) {
                pts.push(k.backproject(u as f64, v as f64, z as f64).cast::<f32>());
            }
        }
    }
    let n = pts.len();
    time(
        &format!("render_depth of {n} points (incl. spacing estimate)"),
        || cgenreg::camera::render::render_depth(&pts, &k, &nalgebra::Isometry3::identity()),
    );
}
