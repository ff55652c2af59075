//! Conversions between 4x4 matrices (as stored in gt.log, pose files, .npy) and typed poses.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};

/// How far the 3x3 block of a pose may be from a rotation: every singular value within this
/// of 1 (a 0.05 % scale). The official 3DMatch gt.log and the 7-Scenes pose files, printed
/// with 7-9 significant digits, stay within 2.6e-4; a 0.1 % scale (1e-3) is refused.
pub const RIGID_TOLERANCE: f64 = 5e-4;

/// Build an isometry from a 4x4 homogeneous matrix whose top-left 3x3 block is a rotation.
/// The rotation is re-orthonormalised (nearest rotation by SVD) so text files with 6-9
/// significant digits still give a proper rotation. Returns None when the matrix is not rigid
/// ([`rigidity_problem`] says why): a non-finite entry, a bottom row other than 0 0 0 1, a
/// 3x3 block with a singular value off 1 by more than [`RIGID_TOLERANCE`] (scale, shear) or
/// with a negative determinant (a mirror).
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
    let sv = r.singular_values();
    if sv.iter().any(|s| (s - 1.0).abs() > RIGID_TOLERANCE) || r.determinant() < 0.0 {
        return None;
    }
    let rot = Rotation3::from_matrix_eps(&r, 1e-12, 100, Rotation3::identity());
    let t = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Some(Isometry3::from_parts(
        t,
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

/// Why [`isometry_from_matrix`] refuses `m` (for error messages), or "a rigid matrix".
pub fn rigidity_problem(m: &Matrix4<f64>) -> String {
    if !m.iter().all(|v| v.is_finite()) {
        return "a non-finite entry".into();
    }
    let row: Vec<f64> = (0..4).map(|c| m[(3, c)]).collect();
    if (0..3).any(|c| row[c].abs() >= 1e-6) || (row[3] - 1.0).abs() >= 1e-6 {
        return format!("last row {} {} {} {}", row[0], row[1], row[2], row[3]);
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let d = r.determinant();
    if d < 0.0 {
        return format!("a mirror (rotation block det {d:.6})");
    }
    let sv = r.singular_values();
    match sv.iter().map(|s| (s - 1.0).abs()).fold(0.0, f64::max) {
        e if e > RIGID_TOLERANCE => format!(
            "a rotation block with singular value {:.6} (scale or shear, off 1 by {e:.1e})",
            sv.iter()
                .copied()
                .max_by(|a, b| (a - 1.0).abs().total_cmp(&(b - 1.0).abs()))
                .unwrap_or(1.0)
        ),
        _ => "a rigid matrix".into(),
    }
}

pub fn matrix_from_isometry(t: &Isometry3<f64>) -> Matrix4<f64> {
    t.to_homogeneous()
}
