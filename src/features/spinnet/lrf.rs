//! The 3DMatch protocol's local reference frame (the authors' `cal_Z_axis` and
//! `RodsRotatFormula`): z is the eigenvector of the smallest eigenvalue of the patch's scatter
//! matrix about the keypoint, turned to face the origin of the cloud's frame (the sensor, for a
//! fragment in its first camera's frame), and the patch is rotated so that z becomes +z. The
//! azimuth stays free: the grid's azimuthal max makes the descriptor invariant to it.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

/// The patch's z axis: `delta` are the points minus the keypoint, `keypoint` the keypoint in
/// the cloud's frame (the authors' `ref_point`, which fixes the sign). None when the scatter
/// has no finite eigen decomposition (a patch of non-finite points).
pub fn z_axis(delta: &[[f32; 3]], keypoint: [f32; 3]) -> Option<Vector3<f64>> {
    let mut cov = Matrix3::<f64>::zeros();
    for d in delta {
        let v = Vector3::new(d[0] as f64, d[1] as f64, d[2] as f64);
        cov += v * v.transpose();
    }
    let eig = SymmetricEigen::try_new(cov, f64::EPSILON, 0)?;
    let i = (0..3).min_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))?;
    let mut z: Vector3<f64> = eig.eigenvectors.column(i).into();
    let n = z.norm();
    if !(n.is_finite() && n > 0.0) {
        return None;
    }
    z /= n;
    let k = Vector3::new(keypoint[0] as f64, keypoint[1] as f64, keypoint[2] as f64);
    // mask = sum(-z * ref_point) < 0: flip so that z points towards the origin
    if (-z).dot(&k) < 0.0 {
        z = -z;
    }
    Some(z)
}

/// The rotation taking `z` onto +z by Rodrigues' formula, as the authors write it: axis
/// z x e_z normalised (zero when z is +-e_z, giving the identity, also for -e_z), angle
/// acos of the cosine between them.
pub fn to_plus_z(z: &Vector3<f64>) -> Matrix3<f64> {
    let e = Vector3::z();
    let c = z.cross(&e);
    let cn = c.norm();
    // F.normalize: c / max(|c|, 1e-12)
    let c = c / cn.max(1e-12);
    // F.cosine_similarity: a.b / max(|a| |b|, 1e-8)
    let cos = z.dot(&e) / (z.norm() * e.norm()).max(1e-8);
    let theta = cos.clamp(-1.0, 1.0).acos();
    let k = Matrix3::new(0.0, -c.z, c.y, c.z, 0.0, -c.x, -c.y, c.x, 0.0);
    Matrix3::identity() + theta.sin() * k + (1.0 - theta.cos()) * (k * k)
}

/// `delta` rotated into the local frame in place (p' = R p, in f32 with R rounded to f32, as
/// the authors' `torch.matmul(delta_x, R^T)`). Returns false (patch unchanged) when no frame
/// exists.
pub fn rotate_into_frame(delta: &mut [[f32; 3]], keypoint: [f32; 3]) -> bool {
    let Some(z) = z_axis(delta, keypoint) else {
        return false;
    };
    let r = to_plus_z(&z).map(|v| v as f32);
    for p in delta.iter_mut() {
        let v = *p;
        for (j, out) in p.iter_mut().enumerate() {
            *out = v[0] * r[(j, 0)] + v[1] * r[(j, 1)] + v[2] * r[(j, 2)];
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tilted_plane_is_rotated_flat_with_its_normal_towards_the_origin() {
        // points of the plane through (0, 0, 2) with normal n (tilted), keypoint on it
        let n = Vector3::new(0.3, -0.2, 1.0).normalize();
        let u = n.cross(&Vector3::x()).normalize();
        let w = n.cross(&u);
        let k = Vector3::new(0.0, 0.0, 2.0);
        let mut delta = Vec::new();
        for i in -5..=5 {
            for j in -5..=5 {
                let p = u * (i as f64 * 0.02) + w * (j as f64 * 0.02);
                delta.push([p.x as f32, p.y as f32, p.z as f32]);
            }
        }
        let kp = [k.x as f32, k.y as f32, k.z as f32];
        let z = z_axis(&delta, kp).unwrap();
        // normal up to sign, and the sign that faces the origin (the origin is at -z of k)
        assert!((z.dot(&n).abs() - 1.0).abs() < 1e-9);
        assert!(z.dot(&(-k)) >= 0.0);
        let r = to_plus_z(&z);
        assert!(((r * z) - Vector3::z()).norm() < 1e-9);
        assert!((r.determinant() - 1.0).abs() < 1e-9);
        assert!(rotate_into_frame(&mut delta, kp));
        assert!(
            delta.iter().all(|p| p[2].abs() < 1e-6),
            "flat after the frame"
        );
    }

    #[test]
    fn the_authors_identity_at_both_poles() {
        assert_eq!(to_plus_z(&Vector3::z()), Matrix3::identity());
        assert_eq!(to_plus_z(&-Vector3::z()), Matrix3::identity());
    }
}
