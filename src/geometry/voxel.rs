//! Voxel-grid downsampling: one point per occupied voxel at the centroid of its points
//! (Open3D's `voxel_down_sample`), with colours, normals and intensity averaged.

use super::{floor_i64, PointCloud};
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Multiplicative hash for the voxel keys: SipHash dominated the run time, and the keys
/// are not attacker-controlled.
#[derive(Default)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u128(&mut self, v: u128) {
        let m = (v as u64) ^ ((v >> 64) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        self.0 = (self.0 ^ m).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 ^= self.0 >> 29;
    }
}

#[derive(Default, Clone)]
struct Acc {
    n: u32,
    p: Vector3<f64>,
    c: [f64; 3],
    nrm: Vector3<f64>,
    i: f64,
    first: usize,
}

/// How far outside the bulk of a cloud a point is a far outlier: more than this many times
/// the extent of the central 98 % (per axis, the largest of the three) beyond it.
pub const FAR_OUTLIER_FACTOR: f64 = 10.0;

/// The bounds of a cloud without its far outliers, and how many there are. The bulk is the
/// 1st-99th percentile box (estimated on at most about 16k evenly spaced points); a point more
/// than [`FAR_OUTLIER_FACTOR`] times the box's largest side outside it is a far outlier (a
/// stray return at 1e30 m, a sentinel value). Without far outliers the bounds are the exact
/// minimum and maximum. None for an empty cloud or one of far outliers only.
pub fn robust_bounds(points: &[Point3<f32>]) -> Option<(Point3<f64>, Point3<f64>, usize)> {
    let first = points.first()?;
    let step = (points.len() / 16_384).max(1);
    let mut box_lo = first.cast::<f64>();
    let mut box_hi = box_lo;
    let mut side = 0f64;
    for k in 0..3 {
        let mut v: Vec<f32> = points.iter().step_by(step).map(|p| p[k]).collect();
        let n = v.len();
        let (a, b) = (n / 100, (n - 1) - n / 100);
        let lo = *v.select_nth_unstable_by(a, f32::total_cmp).1 as f64;
        let hi = *v.select_nth_unstable_by(b, f32::total_cmp).1 as f64;
        box_lo[k] = lo;
        box_hi[k] = hi;
        side = side.max(hi - lo);
    }
    let margin = FAR_OUTLIER_FACTOR * side.max(1e-3);
    let far = |p: &Point3<f32>| {
        (0..3).any(|k| {
            let v = p[k] as f64;
            !(v >= box_lo[k] - margin && v <= box_hi[k] + margin)
        })
    };
    let mut out = 0usize;
    let mut b: Option<(Point3<f64>, Point3<f64>)> = None;
    for p in points {
        if far(p) {
            out += 1;
            continue;
        }
        let q = p.cast::<f64>();
        b = Some(b.map_or((q, q), |(lo, hi)| (lo.inf(&q), hi.sup(&q))));
    }
    b.map(|(lo, hi)| (lo, hi, out))
}

/// Downsample `cloud` on a grid of `voxel` metres anchored, as in Open3D, half a voxel
/// below the cloud's minimum bound (so the same grid, and the same output up to rounding).
/// The bound is [`robust_bounds`]': a far outlier does not move the grid (a point at -1e30
/// would otherwise stretch it until every real point fell into one cell per axis); it keeps a
/// voxel of its own. Output order follows the first point of each voxel in input order, so the
/// result is deterministic. A non-positive voxel size returns a copy.
pub fn voxel_downsample(cloud: &PointCloud, voxel: f64) -> PointCloud {
    if voxel <= 0.0 || cloud.is_empty() {
        return cloud.clone();
    }
    let Some((lo, _, _)) = robust_bounds(&cloud.points) else {
        return cloud.clone();
    };
    let lo = lo - Vector3::repeat(voxel * 0.5);
    let mut cells: HashMap<u128, Acc, BuildHasherDefault<KeyHasher>> =
        HashMap::with_capacity_and_hasher(cloud.len() / 4, Default::default());
    for (idx, p) in cloud.points.iter().enumerate() {
        let q = p.cast::<f64>();
        // Cell indices are >= 0 from the anchor for all but far outliers; 42 bits per axis
        // (signed, 2e12 voxels either way) is more than any cloud at a sane voxel size needs
        // (`as` saturates beyond, so far outliers share the extreme cells, never a real one).
        const HALF: i64 = 1 << 41;
        let c = |v: f64, l: f64| (floor_i64((v - l) / voxel).clamp(-HALF, HALF - 1) + HALF) as u128;
        let key = c(q.x, lo.x) | (c(q.y, lo.y) << 42) | (c(q.z, lo.z) << 84);
        let a = cells.entry(key).or_insert_with(|| Acc {
            first: idx,
            ..Default::default()
        });
        a.n += 1;
        a.p += q.coords;
        if let Some(c) = &cloud.colors {
            for (acc, &v) in a.c.iter_mut().zip(&c[idx]) {
                *acc += v as f64;
            }
        }
        if let Some(ns) = &cloud.normals {
            a.nrm += ns[idx].cast::<f64>();
        }
        if let Some(it) = &cloud.intensity {
            a.i += it[idx] as f64;
        }
    }
    let mut accs: Vec<Acc> = cells.into_values().collect();
    accs.sort_unstable_by_key(|a| a.first);
    let n = |a: &Acc| a.n as f64;
    PointCloud {
        points: accs
            .iter()
            .map(|a| Point3::from((a.p / n(a)).cast::<f32>()))
            .collect(),
        colors: cloud.colors.as_ref().map(|_| {
            accs.iter()
                .map(|a| [0, 1, 2].map(|k| (a.c[k] / n(a)).round().clamp(0.0, 255.0) as u8))
                .collect()
        }),
        normals: cloud.normals.as_ref().map(|_| {
            accs.iter()
                .map(|a| {
                    let v = a.nrm.cast::<f32>();
                    let l = v.norm();
                    if l > 1e-12 {
                        v / l
                    } else {
                        v
                    }
                })
                .collect()
        }),
        intensity: cloud
            .intensity
            .as_ref()
            .map(|_| accs.iter().map(|a| (a.i / n(a)) as f32).collect()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One point at -1e30 (or +1e30 on another axis) neither moves the grid nor merges real
    /// points: the keypoints are those of the cloud without it, plus the outlier's own voxel.
    #[test]
    fn a_far_outlier_does_not_shape_the_grid() {
        let pts: Vec<Point3<f32>> = (0..4000)
            .map(|i| {
                let (a, b, c) = (i % 20, (i / 20) % 20, i / 400);
                Point3::new(
                    a as f32 * 0.05 + 0.01,
                    b as f32 * 0.05 + 0.02,
                    c as f32 * 0.05,
                )
            })
            .collect();
        let clean = voxel_downsample(&PointCloud::from_points(pts.clone()), 0.05);
        assert_eq!(clean.len(), 4000);
        for bad in [
            Point3::new(-1e30, 0.0, 0.0),
            Point3::new(0.3, 1e30, 0.2),
            Point3::new(0.3, 0.2, -3e5),
        ] {
            let mut with = pts.clone();
            with.insert(1234, bad);
            let (lo, hi, n) = robust_bounds(&with).unwrap();
            assert_eq!(n, 1, "{bad}");
            assert!(lo.x > 0.0 && hi.y < 1.0, "{lo} {hi}");
            let down = voxel_downsample(&PointCloud::from_points(with), 0.05);
            assert_eq!(down.len(), 4001, "{bad}");
            let real: Vec<_> = down
                .points
                .iter()
                .filter(|p| p.coords.norm() < 10.0)
                .collect();
            assert_eq!(real.len(), 4000);
            for (a, b) in real.iter().zip(&clean.points) {
                assert!((*a - b).norm() < 1e-6, "{bad}: {a} vs {b}");
            }
        }
        // nothing is a far outlier in an ordinary cloud
        assert_eq!(robust_bounds(&pts).unwrap().2, 0);
    }

    #[test]
    fn centroids_per_voxel_match_brute_force() {
        // Deterministic pseudo-random points.
        let mut s = crate::testing::Lcg(12345);
        let mut rnd = || s.unit31_f32();
        let pts: Vec<Point3<f32>> = (0..5000)
            .map(|_| Point3::new(rnd(), rnd(), rnd()))
            .collect();
        let cloud = PointCloud::from_points(pts.clone());
        let v = 0.1;
        let out = voxel_downsample(&cloud, v);
        // Brute force: group by voxel key with the same anchor.
        let lo = cloud.bounds().unwrap().0.cast::<f64>() - Vector3::repeat(v / 2.0);
        let key = |p: &Point3<f32>| {
            let q = p.cast::<f64>();
            (
                ((q.x - lo.x) / v).floor() as i32,
                ((q.y - lo.y) / v).floor() as i32,
                ((q.z - lo.z) / v).floor() as i32,
            )
        };
        let mut groups: HashMap<(i32, i32, i32), Vec<Point3<f32>>> = HashMap::new();
        for p in &pts {
            groups.entry(key(p)).or_default().push(*p);
        }
        assert_eq!(out.len(), groups.len());
        for q in &out.points {
            // Every output point is the centroid of some group; that group's key is q's key.
            let g = &groups[&key(q)];
            let c = g.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / g.len() as f32;
            assert!((c - q.coords).norm() < 1e-5);
        }
    }

    #[test]
    fn nonpositive_voxel_is_identity() {
        let c =
            PointCloud::from_points(vec![Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0)]);
        assert_eq!(voxel_downsample(&c, 0.0), c);
    }
}
