//! The authors' `var_to_invar`: each voxel's samples (already relative to the voxel centre) are
//! rotated about z by minus the voxel's azimuth index times the azimuth step, so every column of
//! the cylinder sees its samples in the same frame and a rotation of the patch about z becomes a
//! circular shift of the grid, which the network's circular padding and final max absorb.

use super::Geometry;
use std::f64::consts::PI;

/// The rotation of azimuth column `a` as (cos, sin), in f64 then rounded to f32 as the
/// authors build it (numpy, then `torch.FloatTensor`).
pub fn column_rotation(g: &Geometry, a: usize) -> (f32, f32) {
    let step = 2.0 * PI / g.azi_n as f64;
    let angle = -(a as f64 * step);
    (angle.cos() as f32, angle.sin() as f32)
}

/// Rotate every sample of `grouped` ((voxels, voxel_sample, 3), the authors' order) in place.
pub fn var_to_invar(g: &Geometry, grouped: &mut [f32]) {
    let per_voxel = g.voxel_sample * 3;
    let rot: Vec<(f32, f32)> = (0..g.azi_n).map(|a| column_rotation(g, a)).collect();
    for (v, samples) in grouped.chunks_exact_mut(per_voxel).enumerate() {
        let (c, s) = rot[v % g.azi_n];
        for p in samples.chunks_exact_mut(3) {
            let (x, y) = (p[0], p[1]);
            // p' = Rz p with Rz = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
            p[0] = c * x + -s * y;
            p[1] = s * x + c * y;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::spinnet::Protocol;

    #[test]
    fn each_column_is_turned_back_to_the_first() {
        let g = Protocol::Kitti.geometry();
        let centres = super::super::grid::voxel_centres(&g);
        // put each voxel's own centre in as its sample: after the rotation every column of a
        // ring lands on the first column's centre
        let mut grouped: Vec<f32> = centres
            .iter()
            .flat_map(|c| std::iter::repeat_n(*c, g.voxel_sample).flatten())
            .collect();
        var_to_invar(&g, &mut grouped);
        let per_voxel = g.voxel_sample * 3;
        for (v, s) in grouped.chunks_exact(per_voxel).enumerate() {
            let first = centres[v - v % g.azi_n];
            for k in 0..3 {
                assert!(
                    (s[k] - first[k]).abs() < 2e-6,
                    "voxel {v}: {s:?} vs {first:?}"
                );
            }
        }
    }
}
