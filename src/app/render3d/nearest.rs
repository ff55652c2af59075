//! Nearest-neighbour distances for residual colouring: a hash grid whose cell is the
//! saturation distance, so only the 27 surrounding cells are searched. Distances beyond the
//! cap are reported as the cap (the colormap saturates there anyway).

use std::collections::HashMap;

pub struct CappedNearest {
    cell: f32,
    grid: HashMap<[i32; 3], Vec<u32>>,
    points: Vec<[f32; 3]>,
}

impl CappedNearest {
    pub fn new(points: &[[f32; 3]], cap: f32) -> Self {
        let cell = cap.max(1e-6);
        let mut grid: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            grid.entry(key(p, cell)).or_default().push(i as u32);
        }
        Self {
            cell,
            grid,
            points: points.to_vec(),
        }
    }

    /// Index of and distance to the nearest stored point closer than the cap.
    pub fn nearest(&self, q: [f32; 3]) -> Option<(usize, f32)> {
        let k = key(&q, self.cell);
        let mut best: Option<(usize, f32)> = None;
        let cap2 = self.cell * self.cell;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(ids) = self.grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for &i in ids {
                            let p = self.points[i as usize];
                            let d = (p[0] - q[0]).powi(2)
                                + (p[1] - q[1]).powi(2)
                                + (p[2] - q[2]).powi(2);
                            if d < cap2 && best.is_none_or(|b| d < b.1) {
                                best = Some((i as usize, d));
                            }
                        }
                    }
                }
            }
        }
        best.map(|(i, d)| (i, d.sqrt()))
    }

    /// Distance to the nearest stored point, or the cap when none is closer.
    pub fn distance(&self, q: [f32; 3]) -> f32 {
        // A point at exactly the cap is not "closer", and the cap is returned either way.
        self.nearest(q).map_or(self.cell, |(_, d)| d)
    }
}

fn key(p: &[f32; 3], cell: f32) -> [i32; 3] {
    [
        (p[0] / cell).floor() as i32,
        (p[1] / cell).floor() as i32,
        (p[2] / cell).floor() as i32,
    ]
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
