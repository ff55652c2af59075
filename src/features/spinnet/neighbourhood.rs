//! The patch around each keypoint: `points_per_patch` points of the cloud within `des_r`, the
//! keypoint itself last (the network centres the patch on the last point). Each protocol picks
//! them as the authors' test script does, with this crate's seeded generator in place of
//! numpy's (the same distribution, not the same draw):
//! - 3DMatch (`build_patch_input`): a random subset when there are enough neighbours; else
//!   every neighbour, repeated while the patch has room, topped up with a random subset.
//! - KITTI (`select_patches` on a shuffled scan): the first points in the scan's shuffled order
//!   with squared distance < r^2 (f32, the ball-query kernel's test), padded with the first.

use super::{Geometry, Protocol};
use crate::estimate::rng::Pcg32;
use crate::geometry::knn::KdIndex;
use nalgebra::Point3;

/// A cloud prepared for patch extraction: its search index and, for KITTI, the shuffled order.
pub struct PatchSource<'a> {
    points: &'a [Point3<f32>],
    index: KdIndex,
    protocol: Protocol,
    /// KITTI: each point's position in the scan's shuffled order.
    rank: Vec<u32>,
    seed: u64,
}

impl<'a> PatchSource<'a> {
    pub fn new(points: &'a [Point3<f32>], protocol: Protocol, seed: u64) -> PatchSource<'a> {
        let rank = match protocol {
            Protocol::ThreeDMatch => Vec::new(),
            Protocol::Kitti => {
                let mut order: Vec<u32> = (0..points.len() as u32).collect();
                let mut rng = Pcg32::new(seed, u64::MAX);
                for i in (1..order.len()).rev() {
                    let j = rng.below(i as u32 + 1) as usize;
                    order.swap(i, j);
                }
                let mut rank = vec![0u32; points.len()];
                for (pos, &i) in order.iter().enumerate() {
                    rank[i as usize] = pos as u32;
                }
                rank
            }
        };
        PatchSource {
            points,
            index: KdIndex::new(points),
            protocol,
            rank,
            seed,
        }
    }

    /// The patch of keypoint number `i` at `keypoint` (its own generator stream, so patches
    /// can be built in any order or in parallel and come out the same).
    pub fn patch(&self, i: usize, keypoint: &Point3<f32>) -> Vec<[f32; 3]> {
        let g: Geometry = self.protocol.geometry();
        let n = g.points_per_patch;
        let kp = [keypoint.x, keypoint.y, keypoint.z];
        let neigh: Vec<usize> = match self.protocol {
            Protocol::ThreeDMatch => {
                let mut near: Vec<usize> = self
                    .index
                    .within(keypoint, g.des_r as f64)
                    .into_iter()
                    .map(|(j, _)| j)
                    .collect();
                // the kd-tree's distance order holds no meaning for the authors' random draw;
                // index order keeps the draw independent of the tree
                near.sort_unstable();
                let mut rng = Pcg32::new(self.seed, i as u64);
                choose_3dmatch(near.len(), n, &mut rng)
                    .into_iter()
                    .map(|k| near[k])
                    .collect()
            }
            Protocol::Kitti => {
                let r2 = g.des_r * g.des_r;
                let mut near: Vec<usize> = self
                    .index
                    .within(keypoint, g.des_r as f64 * 1.001)
                    .into_iter()
                    .map(|(j, _)| j)
                    .filter(|&j| {
                        let p = &self.points[j];
                        let (dx, dy, dz) = (kp[0] - p.x, kp[1] - p.y, kp[2] - p.z);
                        dx * dx + dy * dy + dz * dz < r2
                    })
                    .collect();
                near.sort_unstable_by_key(|&j| self.rank[j]);
                near.truncate(n);
                if let Some(&first) = near.first() {
                    near.resize(n, first);
                }
                near
            }
        };
        let mut out: Vec<[f32; 3]> = neigh
            .iter()
            .map(|&j| {
                let p = &self.points[j];
                [p.x, p.y, p.z]
            })
            .collect();
        // no neighbour at all (a keypoint away from its cloud): the keypoint alone, repeated
        out.resize(n, kp);
        out[n - 1] = kp;
        out
    }
}

/// `build_patch_input`'s choice of `n` indices among `m` neighbours.
fn choose_3dmatch(m: usize, n: usize, rng: &mut Pcg32) -> Vec<usize> {
    if m == 0 {
        return Vec::new();
    }
    if m >= n {
        return sample_distinct(m, n, rng);
    }
    let mut fix: Vec<usize> = (0..m).collect();
    while m + fix.len() < n {
        fix.extend(0..m);
    }
    let extra = sample_distinct(m, n - fix.len(), rng);
    fix.extend(extra);
    fix
}

/// `k` distinct indices of `0..m` in random order (partial Fisher-Yates).
fn sample_distinct(m: usize, k: usize, rng: &mut Pcg32) -> Vec<usize> {
    let mut all: Vec<usize> = (0..m).collect();
    for i in 0..k.min(m) {
        let j = i + rng.below((m - i) as u32) as usize;
        all.swap(i, j);
    }
    all.truncate(k.min(m));
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize, spread: f32) -> Vec<Point3<f32>> {
        let mut rng = Pcg32::new(3, 0);
        (0..n)
            .map(|_| {
                let mut f = || ((rng.unit_f64() * 2.0 - 1.0) as f32) * spread;
                Point3::new(f(), f(), f())
            })
            .collect()
    }

    #[test]
    fn dense_patches_are_distinct_neighbours_with_the_keypoint_last() {
        for p in Protocol::ALL {
            let g = p.geometry();
            let pts = cloud(60_000, g.des_r * 1.5);
            let src = PatchSource::new(&pts, p, 0);
            let kp = pts[17];
            let patch = src.patch(0, &kp);
            assert_eq!(patch.len(), g.points_per_patch);
            assert_eq!(patch[g.points_per_patch - 1], [kp.x, kp.y, kp.z]);
            let mut seen = std::collections::HashSet::new();
            for q in &patch[..g.points_per_patch - 1] {
                let d2: f32 = (0..3).map(|k| (q[k] - [kp.x, kp.y, kp.z][k]).powi(2)).sum();
                assert!(d2 <= g.des_r * g.des_r * 1.0001, "{d2}");
                assert!(
                    seen.insert(q.map(f32::to_bits)),
                    "a point twice in a dense patch"
                );
            }
            // reproducible, and another keypoint number draws another subset
            assert_eq!(src.patch(0, &kp), patch);
            if p == Protocol::ThreeDMatch {
                assert_ne!(src.patch(1, &kp), patch);
            }
        }
    }

    #[test]
    fn sparse_patches_hold_every_neighbour() {
        for p in Protocol::ALL {
            let g = p.geometry();
            let pts = cloud(3000, g.des_r * 2.0);
            let src = PatchSource::new(&pts, p, 0);
            let kp = pts[5];
            let near: std::collections::HashSet<[u32; 3]> = pts
                .iter()
                .filter(|q| (**q - kp).norm_squared() < g.des_r * g.des_r * 0.999)
                .map(|q| [q.x.to_bits(), q.y.to_bits(), q.z.to_bits()])
                .collect();
            assert!(near.len() > 10 && near.len() < g.points_per_patch);
            let patch = src.patch(0, &kp);
            assert_eq!(patch.len(), g.points_per_patch);
            let got: std::collections::HashSet<[u32; 3]> =
                patch.iter().map(|q| q.map(f32::to_bits)).collect();
            assert!(near.is_subset(&got), "every neighbour is in the patch");
        }
    }

    #[test]
    fn a_keypoint_without_neighbours_gives_a_patch_of_itself() {
        let pts = vec![Point3::new(10.0f32, 0.0, 0.0)];
        let src = PatchSource::new(&pts, Protocol::ThreeDMatch, 0);
        let patch = src.patch(0, &Point3::origin());
        assert!(patch.iter().all(|q| *q == [0.0, 0.0, 0.0]));
    }
}
