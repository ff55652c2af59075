//! Surface normals by local PCA (as Open3D's `estimate_normals` with a hybrid search) and
//! their orientation towards a viewpoint.
//!
//! The normal of a point is the eigenvector of the smallest eigenvalue of the covariance of
//! its neighbourhood (the `max_nn` nearest points within `radius`, the point included).
//! Neighbourhoods with fewer than 3 points, or with all points (nearly) coincident, get a
//! **zero normal**: callers can detect them with `n.norm() == 0`, and FPFH treats them as
//! having no preferred direction. (Open3D substitutes (0, 0, 1) there.)

use super::knn::KdIndex;
use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;

/// Unit normals, one per point, unoriented (the sign is whatever the eigen solver gives);
/// see [`orient_towards_viewpoint`]. `index` must be built over `points`.
pub fn estimate_normals(
    points: &[Point3<f32>],
    index: &KdIndex,
    radius: f64,
    max_nn: usize,
) -> Vec<Vector3<f32>> {
    points
        .par_iter()
        .map_init(Vec::new, |nb, p| {
            // a cancelled run stops here (a zero normal); its stage discards the result
            if crate::cancel::requested() {
                return Vector3::zeros();
            }
            index.hybrid_sq_unsorted_into(p, radius, max_nn, nb);
            normal_of(points, p, nb.iter().map(|e| e.0))
        })
        .collect()
}

/// PCA normal of the points at `idx` (zero when degenerate). Coordinates are taken
/// relative to `origin` (any nearby point) so the covariance keeps its precision far from
/// the world origin.
pub(crate) fn normal_of(
    points: &[Point3<f32>],
    origin: &Point3<f32>,
    idx: impl Iterator<Item = usize>,
) -> Vector3<f32> {
    let mut n = 0usize;
    let mut s = Vector3::<f64>::zeros();
    let mut ss = [0.0f64; 6]; // xx xy xz yy yz zz
    for j in idx {
        let d = (points[j] - origin).cast::<f64>();
        n += 1;
        s += d;
        ss[0] += d.x * d.x;
        ss[1] += d.x * d.y;
        ss[2] += d.x * d.z;
        ss[3] += d.y * d.y;
        ss[4] += d.y * d.z;
        ss[5] += d.z * d.z;
    }
    if n < 3 {
        return Vector3::zeros();
    }
    let inv = 1.0 / n as f64;
    let m = s * inv;
    let c = Matrix3::new(
        ss[0] * inv - m.x * m.x,
        ss[1] * inv - m.x * m.y,
        ss[2] * inv - m.x * m.z,
        ss[1] * inv - m.x * m.y,
        ss[3] * inv - m.y * m.y,
        ss[4] * inv - m.y * m.z,
        ss[2] * inv - m.x * m.z,
        ss[4] * inv - m.y * m.z,
        ss[5] * inv - m.z * m.z,
    );
    smallest_eigenvector(&c)
        .map(|v| v.cast::<f32>())
        .unwrap_or_else(Vector3::zeros)
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric positive semi-definite 3x3
/// matrix: closed-form eigenvalue (trigonometric method) and the best-conditioned cross
/// product of the rows of `A - lambda I`; nalgebra's iterative solver when that is
/// ill-conditioned (two smallest eigenvalues close). None for a (near) zero matrix.
pub(crate) fn smallest_eigenvector(a: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let scale = a.amax();
    if scale.is_nan() || scale <= 1e-30 || !scale.is_finite() {
        return None;
    }
    let a = a / scale;
    let p1 = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let q = a.trace() / 3.0;
    let p2 = (a[(0, 0)] - q).powi(2) + (a[(1, 1)] - q).powi(2) + (a[(2, 2)] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    if p < 1e-12 {
        // Isotropic: no preferred direction.
        return None;
    }
    let b = (a - Matrix3::identity() * q) / p;
    let r = (b.determinant() * 0.5).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let l_max = q + 2.0 * p * phi.cos();
    let l_min = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let l_mid = 3.0 * q - l_max - l_min;
    let m = a - Matrix3::identity() * l_min;
    let (r0, r1, r2) = (
        m.row(0).transpose(),
        m.row(1).transpose(),
        m.row(2).transpose(),
    );
    let cands = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let best = cands
        .iter()
        .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?;
    let nb = best.norm();
    // The cross product has norm ~ (l_max - l_min)(l_mid - l_min); when the smaller gap is
    // tiny relative to the spread, the direction is numerically unreliable.
    let gap = (l_mid - l_min) / (l_max - l_min).max(1e-300);
    if gap > 1e-4 && nb > 1e-20 {
        return Some(best / nb);
    }
    let e = SymmetricEigen::new(a);
    let k = e.eigenvalues.imin();
    let v = e.eigenvectors.column(k).into_owned();
    let n = v.norm();
    (n > 0.0 && n.is_finite()).then(|| v / n)
}

/// Flip every normal that points away from `viewpoint` (n . (viewpoint - p) < 0). The
/// 3DMatch fragments are in the camera frame of their first frame, so the origin is the
/// natural viewpoint there. Zero normals stay zero.
pub fn orient_towards_viewpoint(
    points: &[Point3<f32>],
    normals: &mut [Vector3<f32>],
    viewpoint: Point3<f32>,
) {
    normals
        .par_iter_mut()
        .zip(points.par_iter())
        .for_each(|(n, p)| {
            if n.dot(&(viewpoint - p)) < 0.0 {
                *n = -*n;
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::knn::tests::fragment;
    use crate::testing::Lcg;

    fn angle_deg(a: &Vector3<f32>, b: &Vector3<f32>) -> f32 {
        // Unoriented angle.
        (a.dot(b).abs() / (a.norm() * b.norm()))
            .clamp(0.0, 1.0)
            .acos()
            .to_degrees()
    }

    /// Brute-force neighbourhood + nalgebra's eigen solver.
    /// None when the cut at `max_nn` falls on a distance tie (TSDF-extracted fragments have
    /// many equidistant points), where the chosen neighbours are arbitrary.
    fn brute_normal(
        points: &[Point3<f32>],
        i: usize,
        radius: f32,
        max_nn: usize,
    ) -> Option<Vector3<f32>> {
        let p = points[i];
        let mut nb: Vec<(usize, f32)> = points
            .iter()
            .enumerate()
            .map(|(j, q)| (j, (q - p).norm()))
            .filter(|e| e.1 <= radius)
            .collect();
        nb.sort_by(|a, b| a.1.total_cmp(&b.1));
        if nb.len() > max_nn && nb[max_nn].1 - nb[max_nn - 1].1 < 1e-5 {
            return None;
        }
        nb.truncate(max_nn);
        if nb.len() < 3 {
            return Some(Vector3::zeros());
        }
        let mean = nb.iter().fold(Vector3::<f64>::zeros(), |a, e| {
            a + points[e.0].coords.cast::<f64>()
        }) / nb.len() as f64;
        let c = nb.iter().fold(Matrix3::<f64>::zeros(), |a, e| {
            let d = points[e.0].coords.cast::<f64>() - mean;
            a + d * d.transpose()
        }) / nb.len() as f64;
        let e = SymmetricEigen::new(c);
        Some(
            e.eigenvectors
                .column(e.eigenvalues.imin())
                .into_owned()
                .cast::<f32>(),
        )
    }

    #[test]
    fn closed_form_eigenvector_matches_nalgebra() {
        let mut rng = Lcg(11);
        for t in 0..2000 {
            // Random SPD matrices with a spread of conditioning, including near-planar ones.
            let axis =
                Vector3::new(rng.unit_f32(), rng.unit_f32(), rng.unit_f32()).cast::<f64>() * 6.0;
            let r = nalgebra::Rotation3::new(axis);
            let s = [1.0, 0.3 + rng.unit_f32() as f64, 10f64.powi(-(t % 8) - 1)];
            let c = r.matrix() * Matrix3::from_diagonal(&Vector3::from(s)) * r.matrix().transpose();
            let v = smallest_eigenvector(&c).unwrap();
            let want = r.matrix().column(2).into_owned();
            assert!(
                (v.dot(&want).abs() - 1.0).abs() < 1e-9,
                "t={t}: {v:?} vs {want:?}"
            );
        }
        assert!(smallest_eigenvector(&Matrix3::zeros()).is_none());
        assert!(smallest_eigenvector(&Matrix3::identity()).is_none());
        // Line-like (two equal small eigenvalues): any unit vector orthogonal to the line.
        let line = Matrix3::from_diagonal(&Vector3::new(1.0, 1e-9, 1e-9));
        let v = smallest_eigenvector(&line).unwrap();
        assert!(v.x.abs() < 1e-6 && (v.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn plane_and_sphere_normals_within_one_degree() {
        let mut rng = Lcg(5);
        // Tilted plane through (1, 2, 3) with normal n, points on a 1 m square.
        let n = Vector3::new(0.3f32, -0.5, 0.8).normalize();
        let u = n.cross(&Vector3::x()).normalize();
        let w = n.cross(&u);
        let c0 = Point3::new(1.0f32, 2.0, 3.0);
        let plane: Vec<Point3<f32>> = (0..5000)
            .map(|_| c0 + u * (rng.unit_f32() - 0.5) + w * (rng.unit_f32() - 0.5))
            .collect();
        let index = KdIndex::new(&plane);
        let ns = estimate_normals(&plane, &index, 0.05, 30);
        for m in &ns {
            assert!(angle_deg(m, &n) < 1.0, "plane normal off: {m:?}");
            assert!((m.norm() - 1.0).abs() < 1e-5);
        }
        // Fibonacci sphere of radius 0.5 around c0 (near-uniform); normals radial.
        let m = 20000;
        let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
        let sphere: Vec<Point3<f32>> = (0..m)
            .map(|k| {
                let z = 1.0 - 2.0 * (k as f32 + 0.5) / m as f32;
                let r = (1.0 - z * z).sqrt();
                let th = golden * k as f32;
                c0 + Vector3::new(r * th.cos(), r * th.sin(), z) * 0.5
            })
            .collect();
        let index = KdIndex::new(&sphere);
        let mut ns = estimate_normals(&sphere, &index, 0.04, 30);
        // Viewpoint at the centre: every normal must point inwards after orientation.
        orient_towards_viewpoint(&sphere, &mut ns, c0);
        for (p, m) in sphere.iter().zip(&ns) {
            let radial = (p - c0).normalize();
            let a = (-m.dot(&radial)).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(a < 1.0, "sphere normal off by {a} deg");
        }
    }

    #[test]
    fn matches_brute_force_pca_on_real_fragment() {
        let Some(pts) = fragment("cloud_bin_0.ply") else {
            return;
        };
        let points: Vec<Point3<f32>> = pts.iter().step_by(10).copied().collect();
        let index = KdIndex::new(&points);
        let ns = estimate_normals(&points, &index, 0.05, 30);
        let mut checked = 0;
        for i in (0..points.len()).step_by(211) {
            let Some(want) = brute_normal(&points, i, 0.05, 30) else {
                continue;
            };
            if want.norm() == 0.0 {
                assert_eq!(ns[i].norm(), 0.0);
                continue;
            }
            // Ties at the max_nn boundary can swap a neighbour: allow a small angle.
            let a = angle_deg(&ns[i], &want);
            assert!(a < 0.01, "point {i}: {a} deg, {:?} vs {want:?}", ns[i]);
            checked += 1;
        }
        assert!(checked > 50);
        // Orientation towards the camera at the origin.
        let mut ns2 = ns.clone();
        orient_towards_viewpoint(&points, &mut ns2, Point3::origin());
        for (p, m) in points.iter().zip(&ns2) {
            assert!(m.dot(&(-p.coords)) >= 0.0);
        }
    }

    #[test]
    fn degenerate_neighbourhoods_get_zero_normals() {
        let points = vec![
            Point3::new(0.0f32, 0.0, 0.0),
            Point3::new(0.01, 0.0, 0.0),
            Point3::new(5.0, 5.0, 5.0),
            Point3::new(5.0, 5.0, 5.0),
            Point3::new(5.0, 5.0, 5.0),
        ];
        let index = KdIndex::new(&points);
        let ns = estimate_normals(&points, &index, 0.1, 30);
        // Two points only; three coincident points (zero covariance).
        assert!(ns.iter().all(|n| n.norm() == 0.0));
    }
}
