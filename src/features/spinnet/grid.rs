//! The spherical voxel grid (the authors' `get_voxel_coordinate` / `s2_grid`): rad_n shells,
//! each with ele_n x azi_n centres at the mid elevation and azimuth of each cell. Computed in
//! f64 as numpy does, then rounded to f32 as the authors' `torch.FloatTensor` does, so the
//! ball query sees the same centres bit for bit.

use super::Geometry;
use std::f64::consts::PI;

/// Voxel centres in the authors' order: radial index major, then elevation, then azimuth
/// (index `(r * ele_n + e) * azi_n + a`).
pub fn voxel_centres(g: &Geometry) -> Vec<[f32; 3]> {
    let radius = g.des_r as f64;
    let (rad_n, ele_n, azi_n) = (g.rad_n, g.ele_n, g.azi_n);
    let beta_step = PI / ele_n as f64;
    let alpha_step = 2.0 * PI / azi_n as f64;
    let mut out = Vec::with_capacity(g.voxels());
    for r in 0..rad_n {
        let scale = r as f64 / rad_n as f64 + 1.0 / (2.0 * rad_n as f64);
        for e in 0..ele_n {
            // np.linspace(0, pi, n, endpoint=False) + pi / n / 2
            let beta = e as f64 * beta_step + PI / ele_n as f64 / 2.0;
            for a in 0..azi_n {
                let alpha = a as f64 * alpha_step + PI / azi_n as f64;
                let (st, ct) = (beta.sin(), beta.cos());
                let (sp, cp) = (alpha.sin(), alpha.cos());
                out.push([
                    (scale * (radius * st * cp)) as f32,
                    (scale * (radius * st * sp)) as f32,
                    (scale * (radius * ct)) as f32,
                ]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::spinnet::Protocol;

    #[test]
    fn centres_sit_on_their_shells_in_the_authors_order() {
        for p in Protocol::ALL {
            let g = p.geometry();
            let c = voxel_centres(&g);
            assert_eq!(c.len(), g.voxels());
            for r in 0..g.rad_n {
                let want = g.des_r as f64 * (r as f64 + 0.5) / g.rad_n as f64;
                for i in 0..g.ele_n * g.azi_n {
                    let v = c[r * g.ele_n * g.azi_n + i];
                    let n = (v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>()).sqrt();
                    assert!((n - want).abs() < 1e-6, "shell {r}: {n} vs {want}");
                }
            }
            // the first centre: smallest elevation (near +z), azimuth pi / azi_n
            let v = c[0];
            let az = (v[1] as f64).atan2(v[0] as f64);
            assert!((az - PI / g.azi_n as f64).abs() < 1e-5, "{az}");
            assert!(v[2] > 0.0);
            // azimuth is the fastest index
            let w = c[1];
            let az1 = (w[1] as f64).atan2(w[0] as f64);
            assert!((az1 - 3.0 * PI / g.azi_n as f64).abs() < 1e-5);
        }
    }
}
