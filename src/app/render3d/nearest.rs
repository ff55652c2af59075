//! Nearest-neighbour distances for residual colouring and posterior splats, on the project's
//! k-d tree ([`crate::geometry::knn::KdIndex`]). Distances beyond the cap are reported as the
//! cap (the colormap saturates there anyway).

use crate::geometry::knn::KdIndex;
use nalgebra::Point3;

pub struct CappedNearest {
    cap: f32,
    index: KdIndex,
}

impl CappedNearest {
    pub fn new(points: &[[f32; 3]], cap: f32) -> Self {
        let pts: Vec<Point3<f32>> = points
            .iter()
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect();
        Self {
            cap: cap.max(1e-6),
            index: KdIndex::new(&pts),
        }
    }

    /// Index of and distance to the nearest stored point closer than the cap.
    pub fn nearest(&self, q: [f32; 3]) -> Option<(usize, f32)> {
        self.index
            .nearest(&Point3::new(q[0], q[1], q[2]))
            .filter(|&(_, d)| d < self.cap)
    }

    /// Distance to the nearest stored point, or the cap when none is closer.
    pub fn distance(&self, q: [f32; 3]) -> f32 {
        // A point at exactly the cap is not "closer", and the cap is returned either way.
        self.nearest(q).map_or(self.cap, |(_, d)| d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_brute_force_below_the_cap() {
        let mut s = 12345u64;
        let mut r = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let pts: Vec<[f32; 3]> = (0..3000).map(|_| [r(), r(), r()]).collect();
        let cap = 0.05;
        let nn = CappedNearest::new(&pts, cap);
        for _ in 0..500 {
            let q = [r() * 1.2 - 0.1, r(), r()];
            let brute = pts
                .iter()
                .map(|p| {
                    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                })
                .fold(f32::INFINITY, f32::min)
                .min(cap);
            assert!((nn.distance(q) - brute).abs() < 1e-6, "{q:?}");
        }
    }
}
