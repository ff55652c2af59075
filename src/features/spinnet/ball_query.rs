//! The per-voxel ball query of the authors' `sphere_query` (pointnet2's `ball_query` kernel,
//! then the padding replaced by the voxel centre), followed by the subtraction of the centre:
//! for each voxel the first `voxel_sample` patch points, in patch order, whose squared
//! distance to the centre is below r^2, both computed in f32 exactly as the kernel does.
//! Unfilled samples become the centre (0 after the subtraction); a voxel with no point keeps
//! the patch's point 0 as its first sample (the kernel's index 0), as the authors' code does.
//!
//! The points are binned in a uniform grid of cell `r` so each voxel visits only the cells its
//! ball touches; the candidates are then sorted back into patch order, so the result is the
//! brute-force scan's.

use super::Geometry;

/// A uniform grid over the patch points, cells of side `cell`, each cell's indices ascending.
struct Bins {
    lo: [f32; 3],
    cell: f32,
    dims: [usize; 3],
    start: Vec<u32>,
    idx: Vec<u32>,
}

impl Bins {
    fn new(points: &[[f32; 3]], cell: f32) -> Bins {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in points {
            for k in 0..3 {
                if p[k].is_finite() {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
        if !lo[0].is_finite() {
            lo = [0.0; 3];
            hi = [0.0; 3];
        }
        // bounded: a patch spans at most a few dozen cells per axis; far points share the edge
        let dims = [0, 1, 2].map(|k| (((hi[k] - lo[k]) / cell).floor() as usize + 1).min(512));
        let mut b = Bins {
            lo,
            cell,
            dims,
            start: vec![0; dims[0] * dims[1] * dims[2] + 1],
            idx: vec![0; points.len()],
        };
        let cells: Vec<Option<usize>> = points.iter().map(|p| b.cell_of(p)).collect();
        for c in cells.iter().flatten() {
            b.start[c + 1] += 1;
        }
        for i in 1..b.start.len() {
            b.start[i] += b.start[i - 1];
        }
        let mut fill = b.start.clone();
        for (i, c) in cells.iter().enumerate() {
            if let Some(c) = c {
                b.idx[fill[*c] as usize] = i as u32;
                fill[*c] += 1;
            }
        }
        b
    }

    fn axis(&self, v: f32, k: usize) -> isize {
        ((v - self.lo[k]) / self.cell).floor() as isize
    }

    fn cell_of(&self, p: &[f32; 3]) -> Option<usize> {
        if !p.iter().all(|v| v.is_finite()) {
            return None;
        }
        let c = [0, 1, 2].map(|k| self.axis(p[k], k).clamp(0, self.dims[k] as isize - 1) as usize);
        Some((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0])
    }

    /// Indices in the cells the ball (c, r) touches, appended to `out`.
    fn candidates(&self, c: &[f32; 3], r: f32, out: &mut Vec<u32>) {
        let mut range = [(0usize, 0usize); 3];
        for k in 0..3 {
            let a = self.axis(c[k] - r, k).max(0);
            let b = self.axis(c[k] + r, k).min(self.dims[k] as isize - 1);
            if a > b {
                return;
            }
            range[k] = (a as usize, b as usize);
        }
        for z in range[2].0..=range[2].1 {
            for y in range[1].0..=range[1].1 {
                for x in range[0].0..=range[0].1 {
                    let cell = (z * self.dims[1] + y) * self.dims[0] + x;
                    let (s, e) = (self.start[cell] as usize, self.start[cell + 1] as usize);
                    out.extend_from_slice(&self.idx[s..e]);
                }
            }
        }
    }
}

/// The kernel's squared distance, term by term in f32 (query minus point).
#[inline]
fn d2(c: &[f32; 3], p: &[f32; 3]) -> f32 {
    let (dx, dy, dz) = (c[0] - p[0], c[1] - p[1], c[2] - p[2]);
    dx * dx + dy * dy + dz * dz
}

/// The patch's samples per voxel, relative to each voxel centre: (voxels, voxel_sample, 3)
/// flattened, the authors' `sphere_query(...) - centres` (before `var_to_invar`).
pub fn group(g: &Geometry, local: &[[f32; 3]], centres: &[[f32; 3]]) -> Vec<f32> {
    let ns = g.voxel_sample;
    let r = g.voxel_r;
    let r2 = r * r;
    let bins = Bins::new(local, r);
    let mut out = vec![0.0f32; centres.len() * ns * 3];
    let mut cand = Vec::new();
    let mut found = Vec::with_capacity(ns);
    for (v, c) in centres.iter().enumerate() {
        cand.clear();
        found.clear();
        // a cell edge sits within rounding of the ball: widen the cells visited, the exact
        // test below decides
        bins.candidates(c, r * 1.001 + 1e-6, &mut cand);
        cand.sort_unstable();
        for &i in &cand {
            if d2(c, &local[i as usize]) < r2 {
                found.push(i as usize);
                if found.len() == ns {
                    break;
                }
            }
        }
        let dst = &mut out[v * ns * 3..(v + 1) * ns * 3];
        if found.is_empty() && !local.is_empty() {
            // the kernel's index 0 for every sample; all but the first are masked to the centre
            found.push(0);
        }
        for (k, &i) in found.iter().enumerate() {
            let p = &local[i];
            dst[k * 3] = p[0] - c[0];
            dst[k * 3 + 1] = p[1] - c[1];
            dst[k * 3 + 2] = p[2] - c[2];
        }
        // the rest stays 0: the centre minus itself
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::rng::Pcg32;
    use crate::features::spinnet::Protocol;

    /// The kernel as written: a scan over all points in order.
    fn brute(g: &Geometry, local: &[[f32; 3]], centres: &[[f32; 3]]) -> Vec<f32> {
        let ns = g.voxel_sample;
        let r2 = g.voxel_r * g.voxel_r;
        let mut out = vec![0.0f32; centres.len() * ns * 3];
        for (v, c) in centres.iter().enumerate() {
            let mut idx: Vec<usize> = Vec::new();
            for (k, p) in local.iter().enumerate() {
                if d2(c, p) < r2 {
                    idx.push(k);
                    if idx.len() == ns {
                        break;
                    }
                }
            }
            if idx.is_empty() {
                idx.push(0);
            }
            for (k, &i) in idx.iter().enumerate() {
                for a in 0..3 {
                    out[(v * ns + k) * 3 + a] = local[i][a] - c[a];
                }
            }
        }
        out
    }

    #[test]
    fn binned_query_equals_the_kernels_scan_bit_for_bit() {
        let mut rng = Pcg32::new(7, 1);
        for p in Protocol::ALL {
            let g = p.geometry();
            let centres = super::super::grid::voxel_centres(&g);
            // points in the ball, some duplicated (as padded patches are), some exactly on
            // voxel centres
            let mut local: Vec<[f32; 3]> = (0..2000)
                .map(|_| {
                    let f = |r: &mut Pcg32| ((r.unit_f64() * 2.0 - 1.0) * g.des_r as f64) as f32;
                    [f(&mut rng), f(&mut rng), f(&mut rng)]
                })
                .collect();
            local.extend_from_within(..40);
            local.extend(centres.iter().step_by(97).take(8));
            assert_eq!(group(&g, &local, &centres), brute(&g, &local, &centres));
        }
    }

    #[test]
    fn an_empty_voxel_keeps_point_zero_first_and_the_centre_after() {
        let g = Protocol::ThreeDMatch.geometry();
        let centres = [[0.0f32, 0.0, 0.25]];
        let local = [[0.0f32, 0.0, -0.25], [0.0, 0.0, -0.2]];
        let out = group(&g, &local, &centres);
        assert_eq!(&out[..3], &[0.0, 0.0, -0.5]);
        assert!(out[3..].iter().all(|v| *v == 0.0));
    }
}
