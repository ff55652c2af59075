//! The synthetic UI fixture behind [`InspectorModel::demo`], built from the project's own
//! synthetic scene ([`crate::synth`]): the demo room ([`Scene::demo_room`]) ray-cast along the
//! demo camera path ([`camera_path`], [`render_frame`]) into a target and a source sequence,
//! each back-projected into a cloud in the camera frame of its first frame, with the exact
//! ground truth `inv(P_target0) * P_source0`. The views are frames of those sequences (ray-cast
//! images, labelled as fixture renders). The correspondences are drawn at random around the
//! ground truth, and the posteriors are the library's ([`posterior_row`]) of made-up
//! similarities; the extra pairs, stage times and plots carry made-up values by design.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

use super::*;
use crate::camera::{CameraModel, Intrinsics};
use crate::fusion::{posterior_row, DenseMatrix, FusionParams};
use crate::io::depth_png::DepthImage;
use crate::synth::scene::{hash64, unit, Scene};
use crate::synth::{camera_path, frame_param, render_frame, DemoParams};

/// Frames per sequence; the K = 2 views of a scan are two of them.
const FRAMES: usize = 3;
const K: usize = 2;
/// The sequence index [`frame_param`] takes.
const TARGET_SEQ: usize = 0;
const SOURCE_SEQ: usize = 1;

/// Deterministic draws in [0, 1) from the synthetic scene's hash (a counter stream), so the
/// demo (and its snapshots) never change.
struct Draws {
    seed: u64,
    n: u64,
}

impl Draws {
    fn new(seed: u64) -> Self {
        Self { seed, n: 0 }
    }
    fn f32(&mut self) -> f32 {
        self.n += 1;
        unit(hash64(self.seed ^ hash64(self.n))) as f32
    }
    fn range(&mut self, a: f32, b: f32) -> f32 {
        a + (b - a) * self.f32()
    }
    fn usize(&mut self, n: usize) -> usize {
        ((self.f32() * n as f32) as usize).min(n.saturating_sub(1))
    }
}

fn iso(rx: f64, ry: f64, rz: f64, t: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(rx, ry, rz),
    )
}

fn to_f64(p: [f32; 3]) -> Point3<f64> {
    Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// Camera-to-world pose of frame `i` of sequence `seq`.
fn world_from_camera(seq: usize, i: usize) -> Isometry3<f64> {
    camera_path(frame_param(seq, i, FRAMES))
}

/// The demo room's intrinsics at `width` pixels (4:3).
fn intrinsics(width: u32) -> Intrinsics {
    DemoParams {
        width,
        height: width * 3 / 4,
        ..Default::default()
    }
    .intrinsics()
}

/// One scan: every frame of sequence `seq` ray-cast and back-projected into the camera frame
/// of its first frame, then `n` points taken evenly (the image size grows with `n`).
fn scan(scene: &Scene, seq: usize, n: usize) -> Vec<[f32; 3]> {
    let mut width = 160u32;
    while (FRAMES * (width * width * 3 / 4) as usize) < n && width < 4096 {
        width += 32;
    }
    let k = intrinsics(width);
    let cam0_from_world = world_from_camera(seq, 0).inverse();
    let mut pts = Vec::new();
    for i in 0..FRAMES {
        let pose = world_from_camera(seq, i);
        let (depth, _) = render_frame(scene, &k, &pose, None);
        let cam0_from_cam = cam0_from_world * pose;
        for v in 0..k.height {
            for u in 0..k.width {
                if let Some(z) = depth.meters(u, v) {
                    let q = cam0_from_cam * k.backproject(u as f64, v as f64, z as f64);
                    pts.push([q.x as f32, q.y as f32, q.z as f32]);
                }
            }
        }
    }
    if pts.len() <= n {
        return pts;
    }
    (0..n).map(|i| pts[i * pts.len() / n]).collect()
}

/// A frame of sequence `seq` as a view of its scan: the ray-cast image, its depth colour-mapped,
/// its camera in the scan's frame, and the pixel of each match endpoint it sees (`ends`).
fn view(scene: &Scene, seq: usize, frame: usize, ends: &[[f32; 3]]) -> ViewImage {
    let k = intrinsics(320);
    let pose = world_from_camera(seq, frame);
    let (depth, rgb) = render_frame(scene, &k, &pose, None);
    let cam = ViewCamera {
        cloud_from_camera: world_from_camera(seq, 0).inverse() * pose,
        camera: CameraModel::Pinhole(k),
    };
    let match_pixels = ends.iter().map(|p| pixel_of(&cam, &depth, *p)).collect();
    let side = if seq == SOURCE_SEQ { "src" } else { "tgt" };
    ViewImage {
        label: ViewLabel {
            // A UI test fixture: say so, never name a real generator for these pixels.
            backend: "ui-fixture render (not generated)".into(),
            prompt: "A photo of an indoor scene: a room with a table, a shelf of books, a red sofa and a ball".into(),
            cache_entry: format!("demo/{side}/frame{frame}"),
        },
        rgb: RgbImage {
            width: k.width,
            height: k.height,
            pixels: rgb,
        },
        depth: Some(depth_colors(&depth)),
        camera: Some(cam),
        point_state: Vec::new(),
        match_pixels,
    }
}

/// Depth for display: turbo from near (1 m) to far (5 m), black where there is none.
fn depth_colors(depth: &DepthImage) -> RgbImage {
    let mut out = RgbImage::new(depth.width, depth.height);
    for y in 0..depth.height {
        for x in 0..depth.width {
            if let Some(z) = depth.meters(x, y) {
                let t = ((z - 1.0) / 4.0).clamp(0.0, 1.0);
                out.put(x, y, crate::app::colormap::turbo(1.0 - t));
            }
        }
    }
    out
}

/// The pixel of scan point `p` in a view, when it is inside the image and not occluded.
fn pixel_of(cam: &ViewCamera, depth: &DepthImage, p: [f32; 3]) -> Option<[f32; 2]> {
    let pc = cam.cloud_from_camera.inverse() * to_f64(p);
    let (u, v) = cam.camera.project(&pc)?;
    let (w, h) = cam.camera.size();
    if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
        return None;
    }
    let z = depth.meters(u as u32, v as u32)?;
    (pc.z as f32 <= z + 0.05).then_some([u as f32, v as f32])
}

/// The K frames of sequence `seq` that see the most of `ends`, in frame order.
fn views(scene: &Scene, seq: usize, ends: &[[f32; 3]]) -> Vec<ViewImage> {
    let mut all: Vec<(usize, ViewImage)> = (0..FRAMES)
        .map(|f| (f, view(scene, seq, f, ends)))
        .collect();
    let seen = |v: &ViewImage| v.match_pixels.iter().flatten().count();
    all.sort_by(|a, b| seen(&b.1).cmp(&seen(&a.1)).then(a.0.cmp(&b.0)));
    all.truncate(K);
    all.sort_by_key(|v| v.0);
    all.into_iter().map(|v| v.1).collect()
}

/// Correspondences: 70 % near-true (the nearest target point of a source point under the
/// ground truth, within the overlap), the rest to a random target point.
fn matches(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    gt: &Isometry3<f64>,
    draws: &mut Draws,
) -> Vec<MatchInfo> {
    let stride = (target.len() / 4000).max(1);
    let n_matches = 240;
    let mut matches = Vec::with_capacity(n_matches);
    let mut tries = 0;
    while matches.len() < n_matches && tries < n_matches * 20 {
        tries += 1;
        let s = draws.usize(source.len());
        let q = gt * to_f64(source[s]);
        let (t_true, d) = nearest(target, stride, q);
        if d > 0.08 {
            continue; // outside the overlap
        }
        let t = if draws.f32() < 0.7 {
            t_true
        } else {
            draws.usize(target.len())
        };
        let inlier = (q - to_f64(target[t])).norm() < 0.1;
        let score = if inlier {
            draws.range(0.45, 1.0)
        } else {
            draws.range(0.0, 0.7)
        };
        let branch = match draws.usize(3) {
            0 => Branch::Image,
            1 => Branch::Geometry,
            _ => Branch::Both,
        };
        matches.push(MatchInfo {
            src: s,
            tgt: t,
            score,
            inlier_gt: Some(inlier),
            branch,
            survived: Some(inlier && score > 0.5),
        });
    }
    matches
}

/// The nearest point of a strided subset of `pts` to `q` (brute force keeps the demo fast at
/// 300k points), and its distance.
fn nearest(pts: &[[f32; 3]], stride: usize, q: Point3<f64>) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (i, t) in pts.iter().enumerate().step_by(stride) {
        let d = (to_f64(*t) - q).norm_squared();
        if d < best.1 {
            best = (i, d);
        }
    }
    (best.0, best.1.sqrt())
}

/// The posterior of the source point of match `m` over 300 target points near its true
/// location: made-up image and geometric similarities (the image peaked at the truth with a
/// decoy, the geometry broad) calibrated and fused by the library ([`posterior_row`], the
/// paper's parameters).
fn posterior(
    model: &InspectorModel,
    m: &MatchInfo,
    source_pixel: Option<[f32; 2]>,
    draws: &mut Draws,
) -> Option<Posterior> {
    let (target, gt) = (&model.target, model.ground_truth?);
    let stride = (target.len() / 4000).max(1);
    let q = gt * to_f64(model.source[m.src]);
    let mut cand: Vec<(usize, f64)> = target
        .iter()
        .enumerate()
        .step_by(stride)
        .map(|(i, t)| (i, (to_f64(*t) - q).norm()))
        .collect();
    cand.sort_by(|a, b| a.1.total_cmp(&b.1));
    cand.truncate(300);
    let decoy = to_f64(target[cand.get(cand.len() / 2)?.0]);
    let params = FusionParams::default();
    let (tau_img, tau_geo) = (params.calibration_img.tau(), params.calibration_geo.tau());
    let img: Vec<f32> = cand
        .iter()
        .map(|(i, d)| {
            let dd = (to_f64(target[*i]) - decoy).norm();
            let logit = (-(d * d) / 0.01).max(-(dd * dd) / 0.01 - 0.7) as f32;
            (tau_img * logit).max(-1.0)
        })
        .collect();
    let geo: Vec<f32> = cand
        .iter()
        .map(|(_, d)| (tau_geo * ((-(d * d) / 0.08) as f32 + 0.3 * draws.f32())).max(-1.0))
        .collect();
    let c = cand.len();
    let (img, geo) = (
        DenseMatrix::from_vec(1, c, img).ok()?,
        DenseMatrix::from_vec(1, c, geo).ok()?,
    );
    let row = posterior_row(Some((&img, None, None)), Some(&geo), &params, 0).ok()?;
    let tv = 0;
    let cam = model.target_views.get(tv)?.camera.clone()?;
    let candidate_pixels = cand
        .iter()
        .map(|(i, _)| {
            let pc = cam.cloud_from_camera.inverse() * to_f64(target[*i]);
            let (u, v) = cam.camera.project(&pc)?;
            let (w, h) = cam.camera.size();
            (u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64).then_some([u as f32, v as f32])
        })
        .collect();
    Some(Posterior {
        source_point: m.src,
        source_pixel,
        source_view: 0,
        candidates: cand.iter().map(|c| c.0).collect(),
        image: row.image?,
        geometric: row.geometric?,
        fused: row.fused,
        target_view: tv,
        candidate_pixels,
        gt_target: cand.first().map(|c| c.0),
        survived: m.survived,
        reason: "demo fixture (made-up similarities, library posterior)".into(),
    })
}

/// The demo pair's row, and rows of made-up pairs for the pair browser.
fn pair_rows(rre: f64, rte: f64, correspondences: usize) -> Vec<PairEntry> {
    let mut pairs = vec![PairEntry {
        id: "demo/synth-room 0-1".into(),
        status: PairStatus::Done,
        rre_deg: Some(rre),
        rte_m: Some(rte),
        split: "demo".into(),
        success: Some(rre <= 15.0 && rte <= 0.30),
        inlier_ratio: Some(0.62),
        correspondences: Some(correspondences),
        time_ms: Some(64.0),
        settings: None,
        ..Default::default()
    }];
    for i in 1..8 {
        let e = ((i * 37) % 11) as f64;
        pairs.push(PairEntry {
            id: format!("fixture/pair-{i} (made-up metrics)"),
            status: if i == 5 {
                PairStatus::Failed("no overlap".into())
            } else {
                PairStatus::Done
            },
            rre_deg: (i != 5).then_some(0.4 + e * e * 0.3),
            rte_m: (i != 5).then_some(0.01 + e * 0.012),
            split: if i % 3 == 0 { "3DLoMatch" } else { "3DMatch" }.into(),
            success: (i != 5).then_some(0.4 + e * e * 0.3 <= 15.0 && 0.01 + e * 0.012 <= 0.30),
            inlier_ratio: (i != 5).then_some(0.7 - e * 0.05),
            correspondences: (i != 5).then_some(900 + 37 * i),
            time_ms: Some(40.0 + 11.0 * i as f64),
            settings: None,
            ..Default::default()
        });
    }
    pairs.push(PairEntry::pending(
        "fixture/pair-8 (made-up metrics)",
        "3DMatch",
    ));
    pairs
}

/// Made-up stage states and times.
fn stage_rows() -> Vec<StageInfo> {
    [
        ("read scans", StageState::Cached, Some(12.0)),
        ("depth frames", StageState::Cached, Some(8.5)),
        ("generation (WFM)", StageState::Cached, Some(0.4)),
        ("VFM features", StageState::Cached, Some(3.1)),
        ("FPFH", StageState::Done, Some(41.0)),
        ("calibration", StageState::Done, Some(2.2)),
        ("fusion", StageState::Done, Some(5.7)),
        ("selection", StageState::Done, Some(1.0)),
        ("SC2-PCR", StageState::Done, Some(36.0)),
    ]
    .into_iter()
    .map(|(n, s, t)| StageInfo {
        name: n.into(),
        stage: None,
        state: s,
        time_ms: t,
        role: StageRole::Stage,
    })
    .collect()
}

/// Made-up PR curves, K sweep and prompt study.
fn plot_data() -> PlotData {
    let pr = |name: &str, sharp: f64| PrCurve {
        name: name.into(),
        points: (0..=20)
            .map(|i| {
                let r = i as f64 / 20.0;
                [r, (1.0 - r.powf(sharp)).clamp(0.0, 1.0) * 0.85 + 0.1]
            })
            .collect(),
    };
    PlotData {
        pr_curves: vec![
            pr("Noisy-AND (made-up)", 2.6),
            pr("Noisy-OR (made-up)", 1.4),
        ],
        vs_k: (1..=6)
            .map(|k| KPoint {
                k,
                rre_deg: 4.0 / k as f64 + 0.8,
                rte_m: 0.12 / k as f64 + 0.03,
                pairs: 8,
                skipped: 0,
                recall: Some(1.0),
            })
            .collect(),
        prompt_study: [
            ("no prompt", 3.1, 0.09),
            ("generic", 2.2, 0.07),
            ("scene", 1.6, 0.05),
            ("scene + style", 1.7, 0.055),
            ("adversarial", 5.4, 0.16),
        ]
        .into_iter()
        .map(|(c, r, t)| PromptBar {
            category: c.into(),
            rre_deg: r,
            rte_m: t,
            pairs: 8,
            skipped: 0,
            recall: Some(1.0),
        })
        .collect(),
        vs_k_source: "synthetic UI fixture (made-up values)".into(),
        prompt_source: "synthetic UI fixture (made-up values)".into(),
        study_progress: None,
        figure7_pending: false,
    }
}

/// The demo with (at most) `n` points per cloud.
pub(super) fn build(n: usize) -> InspectorModel {
    let scene = Scene::demo_room();
    let gt = world_from_camera(TARGET_SEQ, 0).inverse() * world_from_camera(SOURCE_SEQ, 0);
    let source = scan(&scene, SOURCE_SEQ, n);
    let target = scan(&scene, TARGET_SEQ, n);
    let mut draws = Draws::new(0x5eed_c0de);
    let matches = matches(&source, &target, &gt, &mut draws);
    let src_ends: Vec<[f32; 3]> = matches.iter().map(|m| source[m.src]).collect();
    let tgt_ends: Vec<[f32; 3]> = matches.iter().map(|m| target[m.tgt]).collect();
    let estimated = iso(0.01, -0.008, 0.004, [0.02, -0.01, 0.015]) * gt;
    let (rre, rte) = pose_errors(&gt, &estimated);
    let mut model = InspectorModel {
        pairs: pair_rows(rre, rte, matches.len()),
        current_pair: Some(0),
        source_views: views(&scene, SOURCE_SEQ, &src_ends),
        target_views: views(&scene, TARGET_SEQ, &tgt_ends),
        source,
        target,
        initial: Isometry3::identity(),
        estimated: Some(estimated),
        ground_truth: Some(gt),
        matches,
        stages: stage_rows(),
        plots: plot_data(),
        ..Default::default()
    };
    // Posteriors for the first 12 matched source points.
    let posteriors: Vec<Posterior> = model
        .matches
        .iter()
        .take(12)
        .enumerate()
        .filter_map(|(i, m)| {
            let pixel = model.source_views.first()?.match_pixels.get(i).copied()?;
            posterior(&model, m, pixel, &mut draws)
        })
        .collect();
    model.default_posterior = posteriors.first().map(|p| p.source_point);
    model.posteriors = posteriors;
    model
}
