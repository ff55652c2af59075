//! The synthetic UI fixture behind [`InspectorModel::demo`].

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

use super::*;
use crate::camera::{CameraModel, Intrinsics};

/// Deterministic xorshift so the demo (and its snapshots) never change.
pub(super) struct Rng(u64);
impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    pub fn range(&mut self, a: f32, b: f32) -> f32 {
        a + (b - a) * self.f32()
    }
    pub fn usize(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// A room corner: floor, two walls, a box and a sphere, with a colour per point.
fn scene(n: usize, rng: &mut Rng) -> Vec<([f32; 3], [u8; 3])> {
    let mut pts = Vec::with_capacity(n);
    while pts.len() < n {
        let r = rng.f32();
        let p;
        let c: [u8; 3];
        if r < 0.3 {
            p = [rng.range(-1.5, 1.5), 1.0, rng.range(1.0, 4.0)];
            let checker = ((p[0] * 2.0).floor() as i32 + (p[2] * 2.0).floor() as i32) & 1;
            c = if checker == 0 {
                [150, 120, 90]
            } else {
                [110, 85, 60]
            };
        } else if r < 0.5 {
            p = [rng.range(-1.5, 1.5), rng.range(-1.0, 1.0), 4.0];
            c = [200, 200, 185];
        } else if r < 0.65 {
            p = [-1.5, rng.range(-1.0, 1.0), rng.range(1.0, 4.0)];
            c = [170, 190, 210];
        } else if r < 0.85 {
            // box on the floor
            let face = rng.usize(3);
            let (u, v) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
            p = match face {
                0 => [0.2 + 0.6 * u, 0.4, 2.2 + 0.6 * v],
                1 => [0.2 + 0.6 * u, 0.4 + 0.6 * v, 2.2],
                _ => [0.2, 0.4 + 0.6 * u, 2.2 + 0.6 * v],
            };
            c = [190, 60, 50];
        } else {
            let (th, ph) = (rng.range(0.0, std::f32::consts::TAU), rng.range(-1.0, 1.0));
            let s = (1.0 - ph * ph).sqrt();
            p = [
                -0.7 + 0.35 * s * th.cos(),
                0.65 + 0.35 * ph,
                2.8 + 0.35 * s * th.sin(),
            ];
            c = [60, 140, 70];
        }
        pts.push((p, c));
    }
    pts
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

/// Splat points into a view image; returns the image, a depth visualisation and a
/// per-pixel index of the nearest point (for pixel lookups).
fn render_view(
    pts: &[([f32; 3], [u8; 3])],
    cam: &ViewCamera,
    tint: [f32; 3],
) -> (RgbImage, RgbImage, Vec<f32>) {
    let (w, h) = cam.camera.size();
    let mut img = RgbImage::new(w, h);
    // background gradient so empty pixels read as "generated sky", not black holes
    for y in 0..h {
        for x in 0..w {
            let g = (40.0 + 60.0 * y as f32 / h as f32) as u8;
            img.put(x, y, [g, g, (g as f32 * 1.2) as u8]);
        }
    }
    let mut zbuf = vec![f32::INFINITY; (w * h) as usize];
    let camera_from_cloud = cam.cloud_from_camera.inverse();
    for (p, c) in pts {
        let pc = camera_from_cloud * to_f64(*p);
        if let Some((u, v)) = cam.camera.project(&pc) {
            let r = (5.0 / pc.z).clamp(1.0, 4.0) as i64;
            let (ui, vi) = (u as i64, v as i64);
            for dy in -r..=r {
                for dx in -r..=r {
                    let (x, y) = (ui + dx, vi + dy);
                    if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                        continue;
                    }
                    let i = (y as u32 * w + x as u32) as usize;
                    if (pc.z as f32) < zbuf[i] {
                        zbuf[i] = pc.z as f32;
                        let shade = (1.2 - 0.12 * pc.z as f32).clamp(0.5, 1.0);
                        let col = [
                            (c[0] as f32 * shade * tint[0]).min(255.0) as u8,
                            (c[1] as f32 * shade * tint[1]).min(255.0) as u8,
                            (c[2] as f32 * shade * tint[2]).min(255.0) as u8,
                        ];
                        img.put(x as u32, y as u32, col);
                    }
                }
            }
        }
    }
    let mut depth = RgbImage::new(w, h);
    for (i, z) in zbuf.iter().enumerate() {
        let (x, y) = (i as u32 % w, i as u32 / w);
        if z.is_finite() {
            let t = ((z - 1.0) / 4.0).clamp(0.0, 1.0);
            depth.put(x, y, crate::app::colormap::turbo(1.0 - t));
        }
    }
    (img, depth, zbuf)
}

fn pixel_of(cam: &ViewCamera, p: [f32; 3], zbuf: &[f32]) -> Option<[f32; 2]> {
    let pc = cam.cloud_from_camera.inverse() * to_f64(p);
    let (u, v) = cam.camera.project(&pc)?;
    let (w, h) = cam.camera.size();
    if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
        return None;
    }
    let z = zbuf[(v as u32 * w + u as u32) as usize];
    // occluded points have no pixel
    (pc.z as f32 <= z + 0.05).then_some([u as f32, v as f32])
}

fn softmax(logits: &[f32]) -> Vec<f32> {
    let m = logits.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
    let e: Vec<f32> = logits.iter().map(|l| (l - m).exp()).collect();
    let s: f32 = e.iter().sum();
    e.iter().map(|x| x / s).collect()
}

pub(super) fn build(n: usize) -> InspectorModel {
    let mut rng = Rng::new(0x5eed_c0de);
    let world = scene(n * 2, &mut rng);
    // Source sees the left part of the room, target the right part; both overlap in the
    // middle. Each cloud lives in its own frame.
    let world_from_source = iso(0.05, 0.35, 0.0, [0.3, 0.0, 0.2]);
    let world_from_target = iso(-0.03, -0.25, 0.02, [-0.4, 0.05, 0.0]);
    let gt = world_from_target.inverse() * world_from_source;
    let src_world: Vec<_> = world
        .iter()
        .filter(|(p, _)| p[0] < 0.6)
        .take(n)
        .cloned()
        .collect();
    let tgt_world: Vec<_> = world
        .iter()
        .filter(|(p, _)| p[0] > -0.9)
        .take(n)
        .cloned()
        .collect();
    let to_frame = |pts: &[([f32; 3], [u8; 3])], world_from: &Isometry3<f64>, rng: &mut Rng| {
        let inv = world_from.inverse();
        pts.iter()
            .map(|(p, c)| {
                let q = inv * to_f64(*p);
                let noise = 0.004;
                (
                    [
                        q.x as f32 + rng.range(-noise, noise),
                        q.y as f32 + rng.range(-noise, noise),
                        q.z as f32 + rng.range(-noise, noise),
                    ],
                    *c,
                )
            })
            .collect::<Vec<_>>()
    };
    let src = to_frame(&src_world, &world_from_source, &mut rng);
    let tgt = to_frame(&tgt_world, &world_from_target, &mut rng);
    let source: Vec<[f32; 3]> = src.iter().map(|(p, _)| *p).collect();
    let target: Vec<[f32; 3]> = tgt.iter().map(|(p, _)| *p).collect();

    // Ground-truth nearest target point for a sample of source points (brute force over
    // a strided subset keeps the demo fast at 300k points).
    let stride = (target.len() / 4000).max(1);
    let nearest_tgt = |q: Point3<f64>| -> (usize, f64) {
        let mut best = (0, f64::INFINITY);
        for (i, t) in target.iter().enumerate().step_by(stride) {
            let d = (to_f64(*t) - q).norm_squared();
            if d < best.1 {
                best = (i, d);
            }
        }
        (best.0, best.1.sqrt())
    };

    // Correspondences: 70 % near-true, the rest random.
    let n_matches = 240;
    let mut matches = Vec::with_capacity(n_matches);
    let mut tries = 0;
    while matches.len() < n_matches && tries < n_matches * 20 {
        tries += 1;
        let s = rng.usize(source.len());
        let q = gt * to_f64(source[s]);
        let (t_true, d) = nearest_tgt(q);
        if d > 0.08 {
            continue; // outside the overlap
        }
        let good = rng.f32() < 0.7;
        let t = if good {
            t_true
        } else {
            rng.usize(target.len())
        };
        let err = (gt * to_f64(source[s]) - to_f64(target[t])).norm();
        let inlier = err < 0.1;
        let score = if inlier {
            rng.range(0.45, 1.0)
        } else {
            rng.range(0.0, 0.7)
        };
        let branch = match rng.usize(3) {
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

    // K = 2 views per scan, looking into the room from the scan's own origin.
    let k = 2;
    let intr = Intrinsics {
        fx: 150.0,
        fy: 150.0,
        cx: 160.0,
        cy: 120.0,
        width: 320,
        height: 240,
    };
    let mk_views = |pts: &[([f32; 3], [u8; 3])], is_src: bool, tint: [f32; 3]| {
        let n = pts.len().max(1) as f64;
        let c = pts.iter().fold(nalgebra::Vector3::zeros(), |a, (p, _)| {
            a + to_f64(*p).coords
        }) / n;
        (0..k)
            .map(|v| {
                // look at the cloud's centroid from 2.3 m away, K views spread in yaw
                let yaw = (v as f64 - (k as f64 - 1.0) / 2.0) * 0.5;
                let back = nalgebra::Vector3::new(-yaw.sin(), -0.45, -yaw.cos()).normalize();
                let eye = c + back * 2.3;
                let z = (c - eye).normalize();
                let x = nalgebra::Vector3::new(0.0, 1.0, 0.0).cross(&z).normalize();
                let y = z.cross(&x);
                let rot = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
                let cam = ViewCamera {
                    cloud_from_camera: Isometry3::from_parts(
                        Translation3::from(eye),
                        UnitQuaternion::from_rotation_matrix(&rot),
                    ),
                    camera: CameraModel::Pinhole(intr),
                };
                let (rgb, depth, zbuf) = render_view(pts, &cam, tint);
                let match_pixels = matches
                    .iter()
                    .map(|m| {
                        let p = if is_src { source[m.src] } else { target[m.tgt] };
                        pixel_of(&cam, p, &zbuf)
                    })
                    .collect();
                ViewImage {
                    label: ViewLabel {
                        // A UI test fixture: say so, never name a real generator for these pixels.
                        backend: "ui-fixture render (not generated)".into(),
                        prompt: "A photo of an indoor scene: a kitchen corner with a red box and a green ball".into(),
                        cache_entry: format!("demo/{}/view{v}", if is_src { "src" } else { "tgt" }),
                    },
                    rgb,
                    depth: Some(depth),
                    camera: Some(cam),
                    point_state: Vec::new(),
                    match_pixels,
                }
            })
            .collect::<Vec<_>>()
    };
    let source_views = mk_views(&src, true, [1.0, 1.0, 1.0]);
    let target_views = mk_views(&tgt, false, [0.95, 1.0, 1.08]);

    // Posteriors for the first 12 matched source points over 300 candidates near the
    // true location.
    let mut posteriors = Vec::new();
    for m in matches.iter().take(12) {
        let q = gt * to_f64(source[m.src]);
        let mut cand: Vec<(usize, f64)> = target
            .iter()
            .enumerate()
            .step_by(stride)
            .map(|(i, t)| (i, (to_f64(*t) - q).norm()))
            .collect();
        cand.sort_by(|a, b| a.1.total_cmp(&b.1));
        cand.truncate(300);
        let gt_target = cand.first().map(|c| c.0);
        // image branch: peaked at the truth with a decoy 0.5 m away; geometry: broad
        let decoy = to_f64(target[cand[cand.len() / 2].0]);
        let image_logits: Vec<f32> = cand
            .iter()
            .map(|(i, d)| {
                let dd = (to_f64(target[*i]) - decoy).norm();
                (-(d * d) / 0.01).max(-(dd * dd) / 0.01 - 0.7) as f32 * 1.0
            })
            .collect();
        let geo_logits: Vec<f32> = cand
            .iter()
            .map(|(_, d)| (-(d * d) / 0.08) as f32 + 0.3 * rng.f32())
            .collect();
        let image = softmax(&image_logits);
        let geometric = softmax(&geo_logits);
        let prod: Vec<f32> = image.iter().zip(&geometric).map(|(a, b)| a * b).collect();
        let s: f32 = prod.iter().sum::<f32>().max(1e-12);
        let fused = prod.iter().map(|p| p / s).collect();
        let tv = 0;
        let cam = target_views[tv].camera.clone();
        let candidate_pixels = cand
            .iter()
            .map(|(i, _)| {
                let cam = cam.as_ref()?;
                let pc = cam.cloud_from_camera.inverse() * to_f64(target[*i]);
                let (u, v) = cam.camera.project(&pc)?;
                (u >= 0.0 && v >= 0.0 && u < intr.width as f64 && v < intr.height as f64)
                    .then_some([u as f32, v as f32])
            })
            .collect();
        let source_pixel = source_views[0].match_pixels[posteriors.len()];
        posteriors.push(Posterior {
            source_point: m.src,
            source_pixel,
            source_view: 0,
            candidates: cand.iter().map(|c| c.0).collect(),
            image,
            geometric,
            fused,
            target_view: tv,
            candidate_pixels,
            gt_target,
            survived: m.survived,
            reason: "demo fixture (made-up posterior)".into(),
        });
    }

    let estimated = iso(0.01, -0.008, 0.004, [0.02, -0.01, 0.015]) * gt;
    let initial = Isometry3::identity();
    let (rre, rte) = pose_errors(&gt, &estimated);
    let mut pairs = vec![PairEntry {
        id: "demo/room-corner 0-1".into(),
        status: PairStatus::Done,
        rre_deg: Some(rre),
        rte_m: Some(rte),
        split: "demo".into(),
        success: Some(rre <= 15.0 && rte <= 0.30),
        inlier_ratio: Some(0.62),
        correspondences: Some(matches.len()),
        time_ms: Some(64.0),
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
        });
    }
    pairs.push(PairEntry::pending(
        "fixture/pair-8 (made-up metrics)",
        "3DMatch",
    ));

    let stages = [
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
        state: s,
        time_ms: t,
        role: crate::app::stages_panel::StageRole::Stage,
    })
    .collect();

    let pr = |name: &str, sharp: f64| PrCurve {
        name: name.into(),
        points: (0..=20)
            .map(|i| {
                let r = i as f64 / 20.0;
                [r, (1.0 - r.powf(sharp)).clamp(0.0, 1.0) * 0.85 + 0.1]
            })
            .collect(),
    };
    let plots = PlotData {
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
    };

    InspectorModel {
        pairs,
        current_pair: Some(0),
        source,
        target,
        initial,
        estimated: Some(estimated),
        ground_truth: Some(gt),
        matches,
        source_views,
        target_views,
        default_posterior: posteriors.first().map(|p: &Posterior| p.source_point),
        posteriors,
        stages,
        plots,
        generation_missing: None,
        image_branch_note: None,
        convention_warning: None,
        hypotheses: None,
    }
}
