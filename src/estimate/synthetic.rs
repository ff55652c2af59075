//! Synthetic correspondence sets for tests and benchmarks: points on the surfaces of a
//! 3 m x 3 m x 2.5 m room (floor, two walls, a table and a cabinet), a known
//! `target_from_source`, a chosen fraction of true matches with Gaussian noise, and outliers that
//! pair random scene points (so outliers follow the same spatial distribution as the scene).

use super::rng::Pcg32;
use nalgebra::{Isometry3, Point3, Vector3};

pub struct SyntheticCorrespondences {
    pub src: Vec<Point3<f32>>,
    pub tgt: Vec<Point3<f32>>,
    pub target_from_source: Isometry3<f64>,
    pub is_inlier: Vec<bool>,
}

/// Axis-aligned boxes whose surfaces make the scene: (min corner, max corner).
const SURFACES: [([f64; 3], [f64; 3]); 5] = [
    ([0.0, 0.0, 0.0], [3.0, 3.0, 0.0]),   // floor
    ([0.0, 0.0, 0.0], [0.0, 3.0, 2.5]),   // wall x = 0
    ([0.0, 0.0, 0.0], [3.0, 0.0, 2.5]),   // wall y = 0
    ([1.2, 1.0, 0.75], [2.2, 1.8, 0.75]), // table top
    ([0.0, 2.2, 0.0], [0.6, 3.0, 1.8]),   // cabinet front
];

fn scene_point(r: &mut Pcg32) -> Point3<f64> {
    let areas: Vec<f64> = SURFACES
        .iter()
        .map(|(a, b)| {
            let e: Vec<f64> = (0..3).map(|k| b[k] - a[k]).filter(|&v| v > 0.0).collect();
            e.iter().product()
        })
        .collect();
    let total: f64 = areas.iter().sum();
    let mut u = r.unit_f64() * total;
    let mut s = 0;
    while s + 1 < SURFACES.len() && u >= areas[s] {
        u -= areas[s];
        s += 1;
    }
    let (a, b) = SURFACES[s];
    Point3::new(
        a[0] + (b[0] - a[0]) * r.unit_f64(),
        a[1] + (b[1] - a[1]) * r.unit_f64(),
        a[2] + (b[2] - a[2]) * r.unit_f64(),
    )
}

/// `n_corr` correspondences over a scene of `n_scene` points, `round(n_corr * inlier_ratio)` of
/// them true matches perturbed by N(0, noise_m) per axis, in random order.
pub fn synthetic_correspondences(
    n_scene: usize,
    n_corr: usize,
    inlier_ratio: f64,
    noise_m: f64,
    seed: u64,
) -> SyntheticCorrespondences {
    let mut r = Pcg32::new(seed, 0x5eed);
    let scene: Vec<Point3<f64>> = (0..n_scene.max(2)).map(|_| scene_point(&mut r)).collect();
    let axis = Vector3::new(r.normal(), r.normal(), r.normal()).normalize();
    let angle = 0.5 + r.unit_f64();
    let t = Vector3::new(r.normal(), r.normal(), r.normal()).normalize() * (0.3 + r.unit_f64());
    let gt = Isometry3::new(t, axis * angle);
    let n_in = ((n_corr as f64) * inlier_ratio).round() as usize;
    let mut order: Vec<usize> = (0..n_corr).collect();
    for i in (1..n_corr).rev() {
        order.swap(i, r.below(i as u32 + 1) as usize);
    }
    let ns = scene.len() as u32;
    let mut src = vec![Point3::origin(); n_corr];
    let mut tgt = vec![Point3::origin(); n_corr];
    let mut is_inlier = vec![false; n_corr];
    for (k, &slot) in order.iter().enumerate() {
        let a = r.below(ns) as usize;
        let (p, q) = if k < n_in {
            let noise = Vector3::new(r.normal(), r.normal(), r.normal()) * noise_m;
            (scene[a], gt * scene[a] + noise)
        } else {
            let mut b = r.below(ns) as usize;
            if b == a {
                b = (b + 1) % scene.len();
            }
            (scene[a], gt * scene[b])
        };
        src[slot] = p.cast();
        tgt[slot] = q.cast();
        is_inlier[slot] = k < n_in;
    }
    SyntheticCorrespondences {
        src,
        tgt,
        target_from_source: gt,
        is_inlier,
    }
}
