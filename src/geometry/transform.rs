//! Conversions between 4x4 matrices (as stored in gt.log, pose files, .npy) and typed poses.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};

/// Build an isometry from a 4x4 homogeneous matrix whose top-left 3x3 block is a rotation.
/// The rotation is re-orthonormalised (nearest rotation by SVD) so text files with 6-9
/// significant digits still give a proper rotation. Returns None when the matrix is not rigid
/// (bottom row not 0 0 0 1, or the 3x3 block far from a rotation).
pub fn isometry_from_matrix(m: &Matrix4<f64>) -> Option<Isometry3<f64>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let bottom_ok = m[(3, 0)].abs() < 1e-6
        && m[(3, 1)].abs() < 1e-6
        && m[(3, 2)].abs() < 1e-6
        && (m[(3, 3)] - 1.0).abs() < 1e-6;
    if !bottom_ok {
        return None;
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let rtr = r.transpose() * r;
    if (rtr - Matrix3::identity()).amax() > 1e-2 || r.determinant() < 0.0 {
        return None;
    }
    let rot = Rotation3::from_matrix_eps(&r, 1e-12, 100, Rotation3::identity());
    let t = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Some(Isometry3::from_parts(
        t,
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

pub fn matrix_from_isometry(t: &Isometry3<f64>) -> Matrix4<f64> {
    t.to_homogeneous()
}
