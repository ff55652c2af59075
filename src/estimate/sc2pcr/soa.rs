//! Correspondence endpoints as structure-of-arrays f32.

use nalgebra::{Isometry3, Point3, Vector3};

/// Correspondence endpoints as structure-of-arrays f32, for vectorised distance loops.
pub(crate) struct Soa {
    pub n: usize,
    sx: Vec<f32>,
    sy: Vec<f32>,
    sz: Vec<f32>,
    tx: Vec<f32>,
    ty: Vec<f32>,
    tz: Vec<f32>,
}

impl Soa {
    pub fn new(src: &[Point3<f32>], tgt: &[Point3<f32>]) -> Self {
        Soa {
            n: src.len(),
            sx: src.iter().map(|p| p.x).collect(),
            sy: src.iter().map(|p| p.y).collect(),
            sz: src.iter().map(|p| p.z).collect(),
            tx: tgt.iter().map(|p| p.x).collect(),
            ty: tgt.iter().map(|p| p.y).collect(),
            tz: tgt.iter().map(|p| p.z).collect(),
        }
    }
    pub fn src64(&self, i: usize) -> Vector3<f64> {
        Vector3::new(self.sx[i] as f64, self.sy[i] as f64, self.sz[i] as f64)
    }
    pub fn tgt64(&self, i: usize) -> Vector3<f64> {
        Vector3::new(self.tx[i] as f64, self.ty[i] as f64, self.tz[i] as f64)
    }
    /// `(Ds, C)` for the pair (i, j): the one formula used everywhere, so that bitsets and
    /// recomputed local matrices agree bit for bit.
    #[inline(always)]
    pub fn cross(&self, i: usize, j: usize) -> (f32, f32) {
        let (dx, dy, dz) = (
            self.sx[i] - self.sx[j],
            self.sy[i] - self.sy[j],
            self.sz[i] - self.sz[j],
        );
        let ds = (dx * dx + dy * dy + dz * dz).sqrt();
        let (ex, ey, ez) = (
            self.tx[i] - self.tx[j],
            self.ty[i] - self.ty[j],
            self.tz[i] - self.tz[j],
        );
        let dt = (ex * ex + ey * ey + ez * ez).sqrt();
        (ds, (ds - dt).abs())
    }
    /// The columns for the `crate::simd` kernels.
    pub fn columns(&self) -> crate::simd::PairColumns<'_> {
        crate::simd::PairColumns {
            src: [&self.sx, &self.sy, &self.sz],
            tgt: [&self.tx, &self.ty, &self.tz],
        }
    }
    /// `‖R p_i + t − q_i‖` in f32 for every correspondence.
    pub fn residuals(&self, t: &Isometry3<f64>) -> Vec<f32> {
        let (r, tr) = rt32(t);
        (0..self.n)
            .map(|i| residual(&r, &tr, self, i))
            .collect::<Vec<f32>>()
    }
    pub fn count_inliers(&self, t: &Isometry3<f64>, thr: f32) -> usize {
        let (r, t) = rt32(t);
        let n = self.n;
        // Over slices (no bounds checks) so that it vectorises; same arithmetic as `residual`.
        let (sx, sy, sz) = (&self.sx[..n], &self.sy[..n], &self.sz[..n]);
        let (tx, ty, tz) = (&self.tx[..n], &self.ty[..n], &self.tz[..n]);
        let mut c = 0u32;
        for i in 0..n {
            let (x, y, z) = (sx[i], sy[i], sz[i]);
            let dx = r[0] * x + r[1] * y + r[2] * z + t[0] - tx[i];
            let dy = r[3] * x + r[4] * y + r[5] * z + t[1] - ty[i];
            let dz = r[6] * x + r[7] * y + r[8] * z + t[2] - tz[i];
            c += ((dx * dx + dy * dy + dz * dz).sqrt() < thr) as u32;
        }
        c as usize
    }
}

fn rt32(t: &Isometry3<f64>) -> ([f32; 9], [f32; 3]) {
    let m = t.rotation.to_rotation_matrix().into_inner();
    let mut r = [0f32; 9];
    for a in 0..3 {
        for b in 0..3 {
            r[a * 3 + b] = m[(a, b)] as f32;
        }
    }
    let v = t.translation.vector;
    (r, [v.x as f32, v.y as f32, v.z as f32])
}

#[inline(always)]
fn residual(r: &[f32; 9], t: &[f32; 3], p: &Soa, i: usize) -> f32 {
    let (x, y, z) = (p.sx[i], p.sy[i], p.sz[i]);
    let dx = r[0] * x + r[1] * y + r[2] * z + t[0] - p.tx[i];
    let dy = r[3] * x + r[4] * y + r[5] * z + t[1] - p.ty[i];
    let dz = r[6] * x + r[7] * y + r[8] * z + t[2] - p.tz[i];
    (dx * dx + dy * dy + dz * dz).sqrt()
}
