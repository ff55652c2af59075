//! mp4 interoperability with ffmpeg: decode libx264 files as Cosmos writes them, have ffmpeg
//! decode ours, and reject non-H.264 tracks clearly. These tests need `ffmpeg`/`ffprobe` on
//! PATH: with CI=true a missing ffmpeg fails the test, otherwise it is skipped with a message.

use cgenreg::wfm::video::{psnr, read_mp4_frames, write_mp4_h264, write_png_frames};
use image::RgbImage;
use std::path::Path;
use std::process::Command;

fn ffmpeg_available() -> bool {
    let ok = |p: &str| {
        Command::new(p)
            .arg("-version")
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false)
    };
    if ok("ffmpeg") && ok("ffprobe") {
        return true;
    }
    if std::env::var("CI").map(|v| v == "true").unwrap_or(false) {
        panic!("CI=true but ffmpeg/ffprobe are not on PATH (apt-get install -y ffmpeg)");
    }
    eprintln!("skipping: ffmpeg/ffprobe not on PATH");
    false
}

fn run(cmd: &mut Command) {
    let out = cmd.output().expect("spawn");
    assert!(
        out.status.success(),
        "{:?} failed: {}",
        cmd,
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Frames that look like a textured indoor scene moving slowly: a shaded plane with a
/// checkerboard, a coloured box, and a gradient, shifting by 2 px per frame.
fn scene_frames(n: usize, w: u32, h: u32) -> Vec<RgbImage> {
    (0..n)
        .map(|t| {
            let s = 2 * t as i64;
            RgbImage::from_fn(w, h, |x, y| {
                let (xs, ys) = (x as i64 + s, y as i64);
                let check = ((xs / 24) + (ys / 24)) % 2 == 0;
                let shade = 80 + (ys * 120 / h as i64) as u8;
                let in_box = (xs - 120).rem_euclid(400) < 90 && (60..150).contains(&ys);
                if in_box {
                    image::Rgb([200, 40 + (xs % 30) as u8, 50])
                } else if check {
                    image::Rgb([shade, shade, shade.saturating_add(30)])
                } else {
                    image::Rgb([shade / 2 + 40, shade / 3 + 60, 70])
                }
            })
        })
        .collect()
}

fn ffprobe_json(path: &Path) -> serde_json::Value {
    let out = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-count_frames",
            "-show_entries",
            "stream=codec_name,r_frame_rate,avg_frame_rate,nb_read_frames,width,height,pix_fmt",
            "-of",
            "json",
        ])
        .arg(path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    v["streams"][0].clone()
}

#[test]
fn decodes_libx264_like_cosmos_writes_it() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let frames = scene_frames(40, 320, 240);
    write_png_frames(&dir.path().join("src"), &frames).unwrap();
    let mp4 = dir.path().join("output.mp4");
    // imageio's mimsave(quality=5): libx264, yuv420p, crf 25; default preset has B-frames.
    run(Command::new("ffmpeg")
        .args(["-y", "-v", "error", "-framerate", "30", "-i"])
        .arg(dir.path().join("src/frame_%06d.png"))
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "25"])
        .arg(&mp4));
    let info = ffprobe_json(&mp4);
    assert_eq!(info["codec_name"], "h264");
    let back = read_mp4_frames(&mp4).unwrap();
    assert_eq!(back.len(), frames.len());
    let mut worst = f64::INFINITY;
    for (i, (a, b)) in frames.iter().zip(&back).enumerate() {
        let q = psnr(a, b).unwrap();
        worst = worst.min(q);
        assert!(q > 30.0, "frame {i}: psnr {q:.2} dB");
        // Display order: each decoded frame matches its own source better than a neighbour.
        if i + 1 < frames.len() {
            assert!(
                q > psnr(&frames[i + 1], b).unwrap(),
                "frame {i} out of order"
            );
        }
    }
    eprintln!("libx264 crf 25 -> our decoder: worst psnr {worst:.2} dB");
}

#[test]
fn ffmpeg_decodes_our_h264() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let frames = scene_frames(45, 640, 480);
    let mp4 = dir.path().join("depth.mp4");
    write_mp4_h264(&mp4, &frames, 30).unwrap();
    let info = ffprobe_json(&mp4);
    assert_eq!(info["codec_name"], "h264", "{info}");
    assert_eq!(info["r_frame_rate"], "30/1", "{info}");
    assert_eq!(info["width"], 640);
    assert_eq!(info["height"], 480);
    assert_eq!(info["nb_read_frames"], "45", "{info}");
    // ffmpeg's own decode of our file matches the sources.
    let out = dir.path().join("dec");
    std::fs::create_dir_all(&out).unwrap();
    run(Command::new("ffmpeg")
        .args(["-y", "-v", "error", "-i"])
        .arg(&mp4)
        .arg(out.join("frame_%06d.png")));
    // ffmpeg numbers from 1.
    for (i, src) in frames.iter().enumerate() {
        let dec = image::open(out.join(format!("frame_{:06}.png", i + 1)))
            .unwrap()
            .to_rgb8();
        let q = psnr(src, &dec).unwrap();
        assert!(q > 30.0, "frame {i}: psnr {q:.2}");
    }
    // And our reader agrees with ffmpeg.
    assert_eq!(read_mp4_frames(&mp4).unwrap().len(), 45);
}

#[test]
fn mpeg4_part2_is_a_clear_error() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    write_png_frames(&dir.path().join("src"), &scene_frames(5, 64, 48)).unwrap();
    let mp4 = dir.path().join("000000_mp4v_video.mp4");
    run(Command::new("ffmpeg")
        .args(["-y", "-v", "error", "-framerate", "30", "-i"])
        .arg(dir.path().join("src/frame_%06d.png"))
        .args(["-c:v", "mpeg4", "-pix_fmt", "yuv420p"])
        .arg(&mp4));
    let e = read_mp4_frames(&mp4).unwrap_err().to_string();
    assert!(e.contains("000000_mp4v_video.mp4"), "{e}");
    assert!(e.contains("mp4v"), "{e}");
    assert!(e.contains("MPEG-4 Part 2"), "{e}");
    assert!(e.contains("H.264"), "{e}");
}
