//! Weighted Kabsch/Horn: the rigid transform minimising `Σ w_i ‖R p_i + t − q_i‖²`.
//!
//! Convention: `src[i]` (source frame) corresponds to `tgt[i]` (target frame); the result is
//! `target_from_source`, so `tgt[i] ≈ T * src[i]`.
//!
//! The rotation is reflection-safe: with `H = Σ w (p − c_p)(q − c_q)ᵀ = U S Vᵀ`,
//! `R = V diag(1, 1, det(V Uᵀ)) Uᵀ` (as `rigid_transform_3d` in SC2-PCR).

use crate::{Error, Result};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Weighted Kabsch with full input checking. `weights` default to 1; they must be finite and
/// non-negative with a positive sum. Points with zero weight are ignored by the degeneracy check.
///
/// Errors: `Error::Shape` for mismatched lengths, `Error::Invalid` for negative weights; `Error::Degenerate` for
/// fewer than 3 points, all weights zero, non-finite input, and identical or collinear points
/// (in either cloud), where the rotation is not determined.
pub fn weighted_kabsch(
    src: &[Point3<f64>],
    tgt: &[Point3<f64>],
    weights: Option<&[f64]>,
) -> Result<Isometry3<f64>> {
    if src.len() != tgt.len() {
        return Err(Error::Shape(format!(
            "kabsch: {} source points but {} target points",
            src.len(),
            tgt.len()
        )));
    }
    if let Some(w) = weights {
        if w.len() != src.len() {
            return Err(Error::Shape(format!(
                "kabsch: {} weights for {} correspondences",
                w.len(),
                src.len()
            )));
        }
        if let Some(i) = w.iter().position(|x| !x.is_finite()) {
            return Err(Error::Degenerate(format!(
                "kabsch: weight {i} is not finite ({})",
                w[i]
            )));
        }
        if let Some(i) = w.iter().position(|&x| x < 0.0) {
            return Err(Error::Invalid(format!(
                "kabsch: weight {i} is negative ({})",
                w[i]
            )));
        }
    }
    let weight = |i: usize| weights.map_or(1.0, |w| w[i]);
    let active = (0..src.len()).filter(|&i| weight(i) > 0.0).count();
    if active < 3 {
        return Err(Error::Degenerate(format!(
            "kabsch: need at least 3 correspondences with positive weight, got {active} (of {})",
            src.len()
        )));
    }
    if let Some(i) = (0..src.len()).find(|&i| {
        !(src[i].coords.iter().all(|v| v.is_finite())
            && tgt[i].coords.iter().all(|v| v.is_finite()))
    }) {
        return Err(Error::Degenerate(format!(
            "kabsch: correspondence {i} has a non-finite coordinate"
        )));
    }
    let get = |i: usize| (src[i].coords, tgt[i].coords, weight(i));
    for (name, pts) in [("source", src), ("target", tgt)] {
        if let Some(what) = spread_problem(pts.len(), |i| (pts[i].coords, weight(i))) {
            return Err(Error::Degenerate(format!(
                "kabsch: the {name} points are {what}"
            )));
        }
    }
    solve(src.len(), get, 0.0)
        .ok_or_else(|| Error::Degenerate("kabsch: SVD of the covariance failed".into()))
}

/// Why a scan's keypoints cannot give a pose (for an error naming the scan): fewer than
/// [`MIN_KEYPOINTS`], or all identical or collinear. None when they can.
pub fn keypoint_problem(points: &[Point3<f32>]) -> Option<String> {
    if points.len() < MIN_KEYPOINTS {
        return Some(format!(
            "has {} keypoint(s); at least {MIN_KEYPOINTS} not on one line are needed",
            points.len()
        ));
    }
    // far outliers (a stray point at 1e30) would dominate the spread: judge the others
    let (lo, hi, _) = crate::geometry::voxel::robust_bounds(points)?;
    let inside: Vec<Vector3<f64>> = points
        .iter()
        .map(|p| p.coords.cast::<f64>())
        .filter(|p| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]))
        .collect();
    if inside.len() < MIN_KEYPOINTS {
        return Some(format!(
            "has {} keypoint(s) apart from far outliers; at least {MIN_KEYPOINTS} not on one \
             line are needed",
            inside.len()
        ));
    }
    spread_problem(inside.len(), |i| (inside[i], 1.0))
        .map(|what| format!("has {} keypoints that are all {what}", points.len()))
}

/// The fewest keypoints a scan may have: SC2-PCR needs 5 correspondences (4 neighbours and a
/// seed), and fewer scan points than that cannot constrain a pose against outliers.
pub const MIN_KEYPOINTS: usize = 5;

/// Whether weighted points fail to determine a rotation: Some("identical") when they have no
/// spread, Some("collinear") when they span a line; None otherwise.
pub(crate) fn spread_problem<F>(n: usize, get: F) -> Option<&'static str>
where
    F: Fn(usize) -> (Vector3<f64>, f64),
{
    let (mut c, mut sw) = (Vector3::zeros(), 0.0);
    for i in 0..n {
        let (p, w) = get(i);
        c += w * p;
        sw += w;
    }
    if sw.is_nan() || sw <= 0.0 {
        return Some("without weight");
    }
    c /= sw;
    let mut cov = Matrix3::zeros();
    for i in 0..n {
        let (p, w) = get(i);
        let d = p - c;
        cov += w * d * d.transpose();
    }
    cov /= sw;
    if !cov.iter().all(|v| v.is_finite()) {
        return Some("not finite");
    }
    let ev = cov.symmetric_eigenvalues();
    let mut ev = [ev[0].max(0.0), ev[1].max(0.0), ev[2].max(0.0)];
    ev.sort_by(|a, b| b.total_cmp(a));
    // Relative to the coordinate magnitude: rounding alone leaves ~1e-32·|c|² of spread.
    if ev[0] <= 1e-20 * (1.0 + c.norm_squared()) {
        Some("identical")
    } else if ev[1] <= 1e-12 * ev[0] {
        Some("collinear")
    } else {
        None
    }
}

/// Weighted centroids `Σ w p / (Σ w + eps)`; returns (source centroid, target centroid, Σ w).
fn centroids<F>(n: usize, get: F, eps: f64) -> (Vector3<f64>, Vector3<f64>, f64)
where
    F: Fn(usize) -> (Vector3<f64>, Vector3<f64>, f64),
{
    let (mut sp, mut sq, mut sw) = (Vector3::zeros(), Vector3::zeros(), 0.0);
    for i in 0..n {
        let (p, q, w) = get(i);
        sp += w * p;
        sq += w * q;
        sw += w;
    }
    (sp / (sw + eps), sq / (sw + eps), sw)
}

/// The unchecked core shared by the estimators: centroids divide by `Σw + eps` (SC2-PCR uses
/// eps = 1e-6). Returns None only when the covariance is not finite or the SVD fails; a
/// degenerate configuration still gives some rotation, as the reference's batched SVD does.
pub(crate) fn solve<F>(n: usize, get: F, eps: f64) -> Option<Isometry3<f64>>
where
    F: Fn(usize) -> (Vector3<f64>, Vector3<f64>, f64),
{
    let (cs, ct, _) = centroids(n, &get, eps);
    let mut h = Matrix3::zeros();
    for i in 0..n {
        let (p, q, w) = get(i);
        h += w * (p - cs) * (q - ct).transpose();
    }
    let r = rotation_from_covariance(&h)?;
    let t = ct - r * cs;
    if !t.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    ))
}

/// `R = V diag(1, 1, det(V Uᵀ)) Uᵀ` for `H = U S Vᵀ` (singular values sorted descending, so the
/// sign flip hits the weakest direction).
pub(crate) fn rotation_from_covariance(h: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    if !h.iter().all(|v| v.is_finite()) {
        return None;
    }
    // nalgebra's sorting SVD panics on NaN, which the check above rules out.
    let svd = nalgebra::SVD::try_new(*h, true, true, f64::EPSILON, 200)?;
    let u = svd.u?;
    let v = svd.v_t?.transpose();
    let d = (v * u.transpose()).determinant();
    let mut e = Matrix3::identity();
    e[(2, 2)] = if d < 0.0 { -1.0 } else { 1.0 };
    let r = v * e * u.transpose();
    r.iter().all(|x| x.is_finite()).then_some(r)
}

/// Gram-Schmidt on the columns of a near-rotation (the reference fallback's clean-up step);
/// keeps a right-handed frame.
pub(crate) fn orthonormalise(r: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let c0 = r.column(0).into_owned();
    let c1 = r.column(1).into_owned();
    let x = c0.try_normalize(1e-300)?;
    let y = (c1 - x * x.dot(&c1)).try_normalize(1e-300)?;
    let z = x.cross(&y);
    Some(Matrix3::from_columns(&[x, y, z]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Lcg;

    fn known() -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(0.3, -1.2, 2.5),
            Vector3::new(0.4, -0.7, 1.1).normalize() * 2.1,
        )
    }

    fn cloud(n: usize, seed: u64) -> Vec<Point3<f64>> {
        let mut s = Lcg(seed);
        (0..n)
            .map(|_| Point3::new(s.unit_f64() * 3.0, s.unit_f64() * 2.0 - 1.0, s.unit_f64()))
            .collect()
    }

    fn assert_close(a: &Isometry3<f64>, b: &Isometry3<f64>, tol: f64) {
        let d = (a.to_homogeneous() - b.to_homogeneous()).abs().max();
        assert!(d < tol, "transforms differ by {d}\n{a}\n{b}");
    }

    #[test]
    fn recovers_known_transform_exactly() {
        let t = known();
        let src = cloud(50, 1);
        let tgt: Vec<_> = src.iter().map(|p| t * p).collect();
        assert_close(&weighted_kabsch(&src, &tgt, None).unwrap(), &t, 1e-9);
        let w: Vec<f64> = (0..50).map(|i| 0.1 + (i % 7) as f64).collect();
        assert_close(&weighted_kabsch(&src, &tgt, Some(&w)).unwrap(), &t, 1e-9);
        // Three points are enough.
        assert_close(
            &weighted_kabsch(&src[..3], &tgt[..3], None).unwrap(),
            &t,
            1e-9,
        );
    }

    #[test]
    fn weights_select_the_consistent_subset() {
        let t = known();
        let src = cloud(40, 2);
        let mut tgt: Vec<_> = src.iter().map(|p| t * p).collect();
        let mut w = vec![1.0; 40];
        for i in 30..40 {
            tgt[i] += Vector3::new(0.5, -0.3, 0.9);
            w[i] = 0.0;
        }
        assert_close(&weighted_kabsch(&src, &tgt, Some(&w)).unwrap(), &t, 1e-9);
        // Without the weights the outliers pull the estimate away.
        let unweighted = weighted_kabsch(&src, &tgt, None).unwrap();
        assert!(
            (unweighted.to_homogeneous() - t.to_homogeneous())
                .abs()
                .max()
                > 1e-3
        );
    }

    #[test]
    fn reflection_gives_a_proper_rotation() {
        // Target is a mirror image of the source: the best proper rotation must have det +1.
        let src = cloud(30, 3);
        let tgt: Vec<_> = src.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let est = weighted_kabsch(&src, &tgt, None).unwrap();
        let r = est.rotation.to_rotation_matrix().into_inner();
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        // Planar points mirrored through their own plane: the proper rotation is exact.
        let planar: Vec<_> = src.iter().map(|p| Point3::new(p.x, p.y, 0.0)).collect();
        let t = known();
        let tgt: Vec<_> = planar.iter().map(|p| t * p).collect();
        assert_close(&weighted_kabsch(&planar, &tgt, None).unwrap(), &t, 1e-9);
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let t = known();
        let src = cloud(10, 4);
        let tgt: Vec<_> = src.iter().map(|p| t * p).collect();
        let deg = |r: Result<Isometry3<f64>>| matches!(r, Err(Error::Degenerate(_)));
        assert!(deg(weighted_kabsch(&src[..2], &tgt[..2], None)));
        assert!(deg(weighted_kabsch(&[], &[], None)));
        assert!(deg(weighted_kabsch(&src, &tgt, Some(&[0.0; 10]))));
        let same = vec![Point3::new(1.0, 2.0, 3.0); 5];
        assert!(deg(weighted_kabsch(&same, &same, None)));
        let line: Vec<_> = (0..6)
            .map(|i| Point3::new(i as f64, 2.0 * i as f64, 1.0 - i as f64))
            .collect();
        let line_t: Vec<_> = line.iter().map(|p| t * p).collect();
        assert!(deg(weighted_kabsch(&line, &line_t, None)));
        let mut nan = src.clone();
        nan[3].y = f64::NAN;
        assert!(deg(weighted_kabsch(&nan, &tgt, None)));
        let mut w = vec![1.0; 10];
        w[2] = f64::INFINITY;
        assert!(deg(weighted_kabsch(&src, &tgt, Some(&w))));
        assert!(matches!(
            weighted_kabsch(&src, &tgt[..9], None),
            Err(Error::Shape(_))
        ));
        w[2] = -1.0;
        assert!(matches!(
            weighted_kabsch(&src, &tgt, Some(&w)),
            Err(Error::Invalid(_))
        ));
        // Only two points carry weight.
        let mut w2 = vec![0.0; 10];
        w2[0] = 1.0;
        w2[5] = 1.0;
        assert!(deg(weighted_kabsch(&src, &tgt, Some(&w2))));
    }

    #[test]
    fn orthonormalise_fixes_a_perturbed_rotation() {
        let r = known().rotation.to_rotation_matrix().into_inner();
        let noisy = r + Matrix3::from_element(1e-4);
        let o = orthonormalise(&noisy).unwrap();
        assert!((o.transpose() * o - Matrix3::identity()).abs().max() < 1e-12);
        assert!((o.determinant() - 1.0).abs() < 1e-12);
        assert!((o - r).abs().max() < 1e-3);
    }
}
