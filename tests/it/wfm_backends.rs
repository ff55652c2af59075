//! WFM backends end to end: a failing and a hanging external command, a fake Cosmos whose
//! output is ingested, a cached Cosmos folder with an empty guardrail folder and a missing one,
//! the oracle, and the built-in generator on real 7-Scenes depth.

use cgenreg::wfm::backend::{GenerateRequest, WfmBackend};
use cgenreg::wfm::builtin::DepthShadeBackend;
use cgenreg::wfm::cached::{CachedBackend, EntryStatus};
use cgenreg::wfm::cosmos::{CosmosBackend, CosmosConfig};
use cgenreg::wfm::depth_video::{build_pair_video, pair_video_from_files};
use cgenreg::wfm::oracle::OracleBackend;
use cgenreg::wfm::prompt::{read_reference_jsonl, write_batch_jsonl, Prompt, PromptPreset};
use cgenreg::wfm::video::{psnr, read_mp4_frames, write_mp4_h264};
use image::RgbImage;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use crate::common;
use crate::common::fake_cosmos_batch;

fn ffmpeg_available() -> bool {
    let ok = Command::new("ffmpeg")
        .arg("-version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok && std::env::var("CI").map(|v| v == "true").unwrap_or(false) {
        panic!("CI=true but ffmpeg is not on PATH (apt-get install -y ffmpeg)");
    }
    if !ok {
        eprintln!("skipping: ffmpeg not on PATH");
    }
    ok
}

/// A small synthetic depth video: a tilted floor and a box moving across, 640x480 like the
/// sensor, encoded exactly as the reference does.
fn depth_video(n: usize) -> Vec<RgbImage> {
    use cgenreg::io::depth_png::DepthImage;
    let frames: Vec<DepthImage> = (0..n)
        .map(|t| {
            let (w, h) = (640u32, 480u32);
            let data = (0..h)
                .flat_map(|v| {
                    (0..w).map(move |u| {
                        let floor = 4000.0 - 2500.0 * v as f64 / h as f64;
                        let in_box = (200 + 4 * t as u32..320 + 4 * t as u32).contains(&u)
                            && (150..300).contains(&v);
                        if v < 20 {
                            0
                        } else if in_box {
                            1200
                        } else {
                            floor as u16
                        }
                    })
                })
                .collect();
            DepthImage {
                width: w,
                height: h,
                data,
            }
        })
        .collect();
    let half = n / 2;
    build_pair_video(&frames[..half], &frames[half..])
}

fn request(pair_id: &str, video: Vec<RgbImage>) -> GenerateRequest {
    GenerateRequest {
        pair_id: pair_id.into(),
        depth_video: video,
        depth_video_path: None,
        prompt: Prompt::from_preset(PromptPreset::General),
        seed: 7,
        source_color: None,
        target_color: None,
    }
}

fn args(a: &[&str]) -> Vec<String> {
    a.iter().map(|s| s.to_string()).collect()
}

#[test]
fn cosmos_failing_command_is_a_clear_error() {
    let work = tempfile::tempdir().unwrap();
    let cfg = CosmosConfig::new(
        args(&[
            "sh",
            "-c",
            "echo 'CUDA out of memory' >&2; exit 1",
            "{batch_input_path}",
        ]),
        work.path(),
        Duration::from_secs(20),
    );
    let b = CosmosBackend::new(cfg).unwrap();
    let t = Instant::now();
    let e = b
        .generate(&request("p/1", depth_video(4)))
        .unwrap_err()
        .to_string();
    assert!(t.elapsed() < Duration::from_secs(10));
    assert!(e.contains("exit status: 1") || e.contains("exited"), "{e}");
    assert!(e.contains("CUDA out of memory"), "{e}");
    assert!(e.contains("cosmos_stderr.log"), "{e}");
    // A program that does not exist.
    let cfg = CosmosConfig::new(
        args(&["/nonexistent/cosmos-transfer"]),
        work.path(),
        Duration::from_secs(5),
    );
    let e = CosmosBackend::new(cfg)
        .unwrap()
        .generate(&request("p/2", depth_video(2)))
        .unwrap_err()
        .to_string();
    assert!(e.contains("could not start"), "{e}");
}

#[test]
fn cosmos_hanging_command_is_killed_on_timeout() {
    let work = tempfile::tempdir().unwrap();
    let cfg = CosmosConfig::new(args(&["sleep", "100"]), work.path(), Duration::from_secs(1));
    let b = CosmosBackend::new(cfg).unwrap();
    let t = Instant::now();
    let e = b
        .generate(&request("hang", depth_video(2)))
        .unwrap_err()
        .to_string();
    let took = t.elapsed();
    assert!(took < Duration::from_secs(5), "took {took:?}");
    assert!(e.contains("timed out"), "{e}");
    // Also the grandchildren of a shell wrapper (like torchrun's workers) die with the group.
    let marker = work.path().join("survived");
    let script = format!("sleep 3 && touch {}", marker.display());
    let cfg = CosmosConfig::new(
        args(&["sh", "-c", &format!("({script}) & wait")]),
        work.path(),
        Duration::from_millis(500),
    );
    let e = CosmosBackend::new(cfg)
        .unwrap()
        .generate(&request("hang2", depth_video(2)))
        .unwrap_err()
        .to_string();
    assert!(e.contains("timed out"), "{e}");
    std::thread::sleep(Duration::from_secs(4));
    assert!(!marker.exists(), "a grandchild survived the timeout kill");
}

/// A stand-in for Cosmos made by the test: reads the batch JSONL it is given, transcodes the
/// depth video to 960x704 libx264 into video_0/output.mp4 and writes prompt.txt.
fn fake_cosmos(dir: &Path) -> PathBuf {
    let p = dir.join("fake_cosmos.sh");
    std::fs::write(
        &p,
        r#"#!/bin/sh
set -e
batch=""; out=""; spec=""; seed=""
while [ $# -gt 0 ]; do
  case "$1" in
    --batch_input_path) batch="$2"; shift 2;;
    --video_save_folder) out="$2"; shift 2;;
    --controlnet_specs) spec="$2"; shift 2;;
    --seed) seed="$2"; shift 2;;
    *) echo "unexpected argument: $1" >&2; exit 2;;
  esac
done
test -f "$spec"
video=$(sed -n 's/.*"input_control": "\([^"]*\)".*/\1/p' "$batch")
mkdir -p "$out/video_0"
echo "fake cosmos: seed $seed, video $video"
ffmpeg -v error -y -i "$video" -vf scale=960:704 -c:v libx264 -pix_fmt yuv420p -crf 18 "$out/video_0/output.mp4"
sed -n 's/^{"prompt": "\([^"]*\)".*/\1/p' "$batch" > "$out/video_0/prompt.txt"
"#,
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    p
}

#[test]
fn cosmos_fake_generator_is_ingested() {
    if !ffmpeg_available() {
        return;
    }
    let work = tempfile::tempdir().unwrap();
    let script = fake_cosmos(work.path());
    let cfg = CosmosConfig::new(
        std::iter::once(script.to_string_lossy().into_owned())
            .chain(common::FAKE_COSMOS_ARGS.iter().map(|a| a.to_string()))
            .collect(),
        work.path().join("jobs"),
        Duration::from_secs(60),
    );
    let b = CosmosBackend::new(cfg).unwrap();
    let video = depth_video(10);
    let req = request("redkitchen/0-5", video.clone());
    let g = b.generate(&req).unwrap();
    assert_eq!(g.frames.len(), 10);
    assert_eq!(g.frames[0].dimensions(), (960, 704));
    let p = &g.provenance;
    assert!(p.backend.starts_with("cosmos:"), "{}", p.backend);
    assert_eq!(p.prompt, req.prompt.text(), "prompt.txt was ingested");
    assert!(p.warnings.is_empty(), "{:?}", p.warnings);
    let argv = p.command.as_ref().unwrap();
    assert!(argv.contains(&"7".to_string()), "seed passed: {argv:?}");
    assert!(
        argv.iter()
            .all(|a| !a.contains("a kitchen") && !a.contains("Scene:")),
        "prompt leaked onto argv: {argv:?}"
    );
    // The generated frame is the depth frame upscaled (the fake copies it): grey levels kept.
    let up = cgenreg::wfm::backend::resize_bilinear(&video[3], 960, 704);
    let q = psnr(&up, &g.frames[3]).unwrap();
    assert!(q > 30.0, "psnr {q}");
    // The batch file is the reference's format and points at the written depth mp4.
    let job = PathBuf::from(p.params["job_dir"].as_str().unwrap());
    let lines = read_reference_jsonl(&job.join("batch_input.jsonl")).unwrap();
    assert_eq!(lines.len(), 1);
    assert_eq!(lines[0].control_weight, Some(1.0));
    assert_eq!(lines[0].prompt, req.prompt.text());
    assert_eq!(
        read_mp4_frames(Path::new(&lines[0].input_control))
            .unwrap()
            .len(),
        10
    );
    let spec: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(job.join("controlnet_spec.json")).unwrap())
            .unwrap();
    assert_eq!(spec["depth"]["control_weight"], 1.0);
    assert!(std::fs::read_to_string(job.join("cosmos_stdout.log"))
        .unwrap()
        .contains("fake cosmos: seed 7"));
}

/// A cached Cosmos folder like the authors' (§2.7), three lines: present, empty, missing.
fn cached_fixture(dir: &Path) -> (PathBuf, PathBuf, Vec<RgbImage>) {
    let out = dir.join("3dmatch_rgb_gen_vids");
    let frames: Vec<RgbImage> = (0..6)
        .map(|t| {
            RgbImage::from_fn(96, 64, |x, y| {
                image::Rgb([(x * 2 + t * 5) as u8, (y * 3) as u8, 100])
            })
        })
        .collect();
    std::fs::create_dir_all(out.join("video_0")).unwrap();
    write_mp4_h264(&out.join("video_0/output.mp4"), &frames, 30).unwrap();
    std::fs::write(out.join("video_0/prompt.txt"), "A photorealistic kitchen\n").unwrap();
    std::fs::create_dir_all(out.join("video_1")).unwrap(); // guardrail: empty
    let spec = dir.join("3dmatch_test.json");
    write_batch_jsonl(
        &spec,
        &[
            (
                "A photorealistic kitchen".into(),
                PathBuf::from("/my_data_path/v/000000_7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050.mp4"),
            ),
            ("B".into(), PathBuf::from("/my_data_path/v/000001_x-seq-01_frame-000000@seq-01_frame-000100.mp4")),
            ("C".into(), PathBuf::from("/my_data_path/v/000002_x-seq-01_frame-000000@seq-01_frame-000150.mp4")),
        ],
        1.0,
    )
    .unwrap();
    (out, spec, frames)
}

#[test]
fn cached_folder_with_guardrail_and_missing_entries() {
    let dir = tempfile::tempdir().unwrap();
    let (out, spec, frames) = cached_fixture(dir.path());
    let b = CachedBackend::open(&out, &spec).unwrap();
    let r = b.report().unwrap();
    assert_eq!(r.entries[0].status, EntryStatus::Present);
    assert_eq!(r.entries[1].status, EntryStatus::EmptyGuardrail);
    assert_eq!(r.entries[2].status, EntryStatus::Missing);
    assert_eq!(
        r.summary(),
        "3 lines: 1 present, 1 empty (guardrail), 1 missing"
    );

    // Line 0 by number, by video name, and by the depth mp4's file name.
    let mut req = request("0", vec![]);
    req.prompt = Prompt::verbatim("A photorealistic kitchen");
    let g = b.generate(&req).unwrap();
    assert_eq!(g.frames.len(), frames.len());
    assert!(psnr(&frames[2], &g.frames[2]).unwrap() > 35.0);
    assert_eq!(g.provenance.prompt, "A photorealistic kitchen");
    assert!(
        g.provenance.warnings.is_empty(),
        "{:?}",
        g.provenance.warnings
    );
    assert_eq!(g.provenance.params["line"], 0);
    req.pair_id = "7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050".into();
    assert_eq!(b.line_for(&req).unwrap(), 0);
    req.pair_id = "whatever".into();
    req.depth_video_path = Some(PathBuf::from(
        "/elsewhere/000000_7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050.mp4",
    ));
    assert_eq!(b.line_for(&req).unwrap(), 0);

    // A different requested prompt is reported, not hidden.
    let g = b.generate(&request("0", vec![])).unwrap();
    assert!(g
        .provenance
        .warnings
        .iter()
        .any(|w| w.contains("different prompt")));

    let e = b.generate(&request("1", vec![])).unwrap_err().to_string();
    assert!(
        e.contains("video_1") && e.contains("guardrail") && e.contains("line 2"),
        "{e}"
    );
    let e = b.generate(&request("2", vec![])).unwrap_err().to_string();
    assert!(e.contains("video_2") && e.contains("no such folder"), "{e}");
    let e = b.generate(&request("3", vec![])).unwrap_err().to_string();
    assert!(e.contains("3 lines"), "{e}");
    let e = b
        .generate(&request("kitchen/0-1", vec![]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not in"), "{e}");
}

#[test]
fn cached_spec_with_shifted_positions_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let spec = dir.path().join("spec.json");
    write_batch_jsonl(
        &spec,
        &[
            ("a".into(), PathBuf::from("/v/000000_a.mp4")),
            ("c".into(), PathBuf::from("/v/000002_c.mp4")),
        ],
        1.0,
    )
    .unwrap();
    let e = CachedBackend::open(&out, &spec).err().unwrap().to_string();
    assert!(
        e.contains("spec.json") && e.contains("line 2") && e.contains("000002_c.mp4"),
        "{e}"
    );
    assert!(CachedBackend::open(&dir.path().join("nope"), &spec).is_err());
}

#[test]
fn oracle_returns_real_frames_labelled() {
    let dir = tempfile::tempdir().unwrap();
    let mut paths = Vec::new();
    for i in 0..4u8 {
        let p = dir.path().join(format!("frame-{i:06}.color.jpg"));
        RgbImage::from_pixel(64, 48, image::Rgb([40 * i + 20, 100, 200 - 30 * i]))
            .save(&p)
            .unwrap();
        paths.push(p);
    }
    let mut req = request("p", vec![]);
    let b = OracleBackend::default();
    assert!(b.generate(&req).unwrap_err().to_string().contains("colour"));
    req.source_color = Some(paths[..2].to_vec());
    req.target_color = Some(paths[2..].to_vec());
    let g = b.generate(&req).unwrap();
    assert_eq!(g.provenance.model, "oracle (real RGB)");
    assert_eq!(g.provenance.backend, "oracle");
    assert_eq!(g.frames.len(), 4);
    for (i, f) in g.frames.iter().enumerate() {
        let p = f.get_pixel(10, 10).0;
        assert!(
            (p[0] as i32 - (40 * i as i32 + 20)).abs() <= 3,
            "{i}: {p:?}"
        );
    }
    let g = OracleBackend {
        resize_to: Some((96, 72)),
    }
    .generate(&req)
    .unwrap();
    assert_eq!(g.frames[0].dimensions(), (96, 72));
    // A frame-count mismatch with the depth video is an error.
    req.depth_video = depth_video(6);
    assert!(b.generate(&req).is_err());
}

#[test]
fn real_redkitchen_depth_video_builtin_and_oracle() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let seq = root.join("7scenes-redkitchen-rgbd");
    let depth = |i: usize| seq.join(format!("frame-{i:06}.depth.png"));
    let color = |i: usize| seq.join(format!("frame-{i:06}.color.jpg"));
    // Fragment 0 (frames 0-49) then fragment 1 (50-99), as the reference's line 0.
    let src: Vec<PathBuf> = (0..50).map(depth).collect();
    let tgt: Vec<PathBuf> = (50..100).map(depth).collect();
    let t = Instant::now();
    let video = pair_video_from_files(&src, &tgt).unwrap();
    eprintln!(
        "encode 100 depth frames: {:.2} s",
        t.elapsed().as_secs_f64()
    );
    assert_eq!(video.len(), 100);
    assert_eq!(video[0].dimensions(), (640, 480));
    // Every frame spans the normalised range: nearest valid pixel 254, invalid pixels 0.
    for f in &video {
        let max = f.as_raw().iter().max().copied().unwrap();
        assert!((250..=255).contains(&max), "max {max}");
        assert!(f.as_raw().contains(&0));
    }

    let dir = tempfile::tempdir().unwrap();
    let mp4 = dir
        .path()
        .join("000000_7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050.mp4");
    let t = Instant::now();
    write_mp4_h264(&mp4, &video, 30).unwrap();
    eprintln!(
        "write H.264 mp4 (100 frames 640x480): {:.2} s, {} kB",
        t.elapsed().as_secs_f64(),
        std::fs::metadata(&mp4).unwrap().len() / 1024
    );
    let t = Instant::now();
    let back = read_mp4_frames(&mp4).unwrap();
    eprintln!("read it back: {:.2} s", t.elapsed().as_secs_f64());
    let worst = video
        .iter()
        .zip(&back)
        .map(|(a, b)| psnr(a, b).unwrap())
        .fold(f64::INFINITY, f64::min);
    assert!(worst > 38.0, "depth video psnr {worst}");

    let mut req = request("redkitchen/0-1", video);
    req.depth_video_path = Some(mp4);
    let t = Instant::now();
    let g = DepthShadeBackend::default().generate(&req).unwrap();
    eprintln!(
        "builtin-depthshade-v1, 100 frames at 960x704: {:.2} s",
        t.elapsed().as_secs_f64()
    );
    assert_eq!(g.frames.len(), 100);
    assert_eq!(g.frames[0].dimensions(), (960, 704));
    assert!(g.provenance.model.contains("NOT a WFM"));
    // Neighbouring frames look alike; frames a fragment apart do not look identical.
    let near = psnr(&g.frames[10], &g.frames[11]).unwrap();
    let far = psnr(&g.frames[10], &g.frames[60]).unwrap();
    assert!(near > far, "near {near} far {far}");

    req.source_color = Some((0..50).map(color).collect());
    req.target_color = Some((50..100).map(color).collect());
    let g = OracleBackend::default().generate(&req).unwrap();
    assert_eq!(g.frames.len(), 100);
    assert_eq!(g.frames[0].dimensions(), (640, 480));
}

#[test]
fn cosmos_batch_runs_once_per_seed_and_keeps_lines_aligned() {
    if !ffmpeg_available() {
        return;
    }
    let work = tempfile::tempdir().unwrap();
    let script = fake_cosmos_batch(work.path());
    let cfg = CosmosConfig::new(
        std::iter::once(script.to_string_lossy().into_owned())
            .chain(common::FAKE_COSMOS_ARGS.iter().map(|a| a.to_string()))
            .collect(),
        work.path().join("jobs"),
        Duration::from_secs(120),
    );
    let b = CosmosBackend::new(cfg).unwrap();
    // Four pairs with different videos (so a swapped line shows), one blocked by the
    // "guardrail", one with another seed.
    let videos: Vec<Vec<RgbImage>> = [6, 8, 10, 4].iter().map(|&n| depth_video(n)).collect();
    let mut reqs: Vec<GenerateRequest> = videos
        .iter()
        .enumerate()
        .map(|(i, v)| request(&format!("redkitchen/{i}-{}", i + 1), v.clone()))
        .collect();
    reqs[1].prompt = Prompt::verbatim("BLOCKED by the guardrail");
    reqs[3].seed = 9;
    let out = b.generate_batch(&reqs);
    assert_eq!(out.len(), 4);
    let runs = std::fs::read_to_string(work.path().join("runs.log")).unwrap();
    assert_eq!(runs, "seed 7\nseed 9\n", "one run per seed");
    for i in [0usize, 2, 3] {
        let g = out[i].as_ref().unwrap_or_else(|e| panic!("line {i}: {e}"));
        assert_eq!(
            g.frames.len(),
            videos[i].len(),
            "line {i} got its own video"
        );
        let up = cgenreg::wfm::backend::resize_bilinear(&videos[i][1], 960, 704);
        let q = psnr(&up, &g.frames[1]).unwrap();
        assert!(q > 30.0, "line {i}: psnr {q}");
        assert_eq!(g.provenance.seed, reqs[i].seed);
        assert_eq!(g.provenance.prompt, reqs[i].prompt.text());
    }
    let blocked = out[1].as_ref().expect_err("blocked line fails").to_string();
    assert!(blocked.contains("guardrail"), "{blocked}");
    // The seed-7 batch is one job with the reference's JSONL: three lines, i_gen_vid.
    let g0 = out[0].as_ref().unwrap();
    assert_eq!(g0.provenance.params["batch_size"], 3);
    assert_eq!(g0.provenance.params["batch_line"], 0);
    assert_eq!(out[2].as_ref().unwrap().provenance.params["batch_line"], 2);
    let job = PathBuf::from(g0.provenance.params["job_dir"].as_str().unwrap());
    let lines = read_reference_jsonl(&job.join("batch_input.jsonl")).unwrap();
    assert_eq!(lines.len(), 3);
    assert_eq!(lines[2].video_save_name.as_deref(), Some("2_gen_vid"));
    // The single-seed-9 batch is a batch of one: same layout as `generate`.
    let g3 = out[3].as_ref().unwrap();
    assert!(g3.provenance.params.get("batch_size").is_none());
}
