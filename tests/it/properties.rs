//! Invariants checked with proptest over generated inputs (poses, voxel grid, k-NN against
//! brute force, calibrated rows, the Noisy-AND odds form, readers round-tripping their
//! writers). A failure prints the shrunk input; proptest also records its seed under
//! `proptest-regressions/` so the same case runs first next time.

use cgenreg::fusion::{calibrate, noisy_and, Calibration, DenseMatrix};
use cgenreg::geometry::knn::KdIndex;
use cgenreg::geometry::transform::{isometry_from_matrix, matrix_from_isometry};
use cgenreg::geometry::voxel::voxel_downsample;
use cgenreg::geometry::PointCloud;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use std::collections::HashSet;
use std::path::Path;

fn point() -> impl Strategy<Value = Point3<f32>> {
    (-5.0f32..5.0, -5.0f32..5.0, -5.0f32..5.0).prop_map(|(x, y, z)| Point3::new(x, y, z))
}

fn pose() -> impl Strategy<Value = Isometry3<f64>> {
    (
        -3.2f64..3.2,
        -1.5f64..1.5,
        -3.2f64..3.2,
        -10.0f64..10.0,
        -10.0f64..10.0,
        -10.0f64..10.0,
    )
        .prop_map(|(r, p, y, tx, ty, tz)| {
            Isometry3::from_parts(
                Translation3::new(tx, ty, tz),
                UnitQuaternion::from_euler_angles(r, p, y),
            )
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// A pose survives its 4x4 matrix, and T * T^-1 is the identity.
    #[test]
    fn pose_matrix_round_trip(t in pose(), p in point()) {
        let back = isometry_from_matrix(&matrix_from_isometry(&t)).expect("a rigid matrix");
        let p = p.cast::<f64>();
        prop_assert!((back * p - t * p).norm() < 1e-9);
        prop_assert!(((t * t.inverse()) * p - p).norm() < 1e-9);
    }

    /// k-NN of the k-d tree equals brute force (distances; indices up to ties).
    #[test]
    fn knn_matches_brute_force(
        pts in prop::collection::vec(point(), 1..300),
        q in point(),
        k in 1usize..12,
    ) {
        let idx = KdIndex::new(&pts);
        let got = idx.knn(&q, k);
        let mut want: Vec<f32> = pts.iter().map(|p| (p - q).norm()).collect();
        want.sort_by(|a, b| a.partial_cmp(b).unwrap());
        want.truncate(k);
        prop_assert_eq!(got.len(), want.len());
        for ((i, d), w) in got.iter().zip(&want) {
            let d_true = (pts[*i] - q).norm();
            // the reported distance (m) is the point's own, and the k-th smallest
            prop_assert!((d - d_true).abs() <= 1e-4 * (1.0 + d_true), "{d} vs {d_true}");
            prop_assert!((d_true - w).abs() <= 1e-4 * (1.0 + w), "{d_true} vs {w}");
        }
    }

    /// Voxel downsampling keeps one point per occupied voxel of the grid anchored half a
    /// voxel below the minimum bound (as Open3D), inside that voxel.
    #[test]
    fn voxel_grid_one_point_per_occupied_voxel(
        pts in prop::collection::vec(point(), 1..400),
        voxel in 0.2f64..2.0,
    ) {
        let lo = pts.iter().fold([f64::INFINITY; 3], |m, p| {
            [m[0].min(p.x as f64), m[1].min(p.y as f64), m[2].min(p.z as f64)]
        });
        let key = |p: &Point3<f32>| {
            let c = |x: f32, l: f64| ((x as f64 - (l - voxel / 2.0)) / voxel).floor() as i64;
            (c(p.x, lo[0]), c(p.y, lo[1]), c(p.z, lo[2]))
        };
        let occupied: HashSet<_> = pts.iter().map(key).collect();
        let out = voxel_downsample(&PointCloud::from_points(pts.clone()), voxel);
        prop_assert_eq!(out.points.len(), occupied.len());
        for p in &out.points {
            // a centroid of points in one voxel lies in that voxel (up to f32 rounding at
            // the boundary)
            let near: Vec<_> = [-1e-4f32, 0.0, 1e-4]
                .iter()
                .map(|e| key(&Point3::new(p.x + e, p.y + e, p.z + e)))
                .collect();
            prop_assert!(near.iter().any(|k| occupied.contains(k)), "{p:?} in no occupied voxel");
        }
    }

    /// Both calibrations give rows in [0, 1]; the row softmax's rows sum to 1.
    #[test]
    fn calibrated_rows_are_distributions(
        rows in 1usize..12,
        cols in 1usize..40,
        seed in any::<u64>(),
        tau in 0.01f32..1.0,
    ) {
        let mut s = cgenreg::testing::Lcg(seed);
        let data: Vec<f32> = (0..rows * cols)
            .map(|_| s.signed_f32())
            .collect();
        let sim = DenseMatrix::from_vec(rows, cols, data).unwrap();
        let row = calibrate(&sim, None, None, Calibration::RowSoftmax { tau }).unwrap();
        for r in 0..rows {
            let x = &row.data[r * cols..(r + 1) * cols];
            let sum: f32 = x.iter().sum();
            prop_assert!((sum - 1.0).abs() < 1e-4, "row {r} sums to {sum}");
            prop_assert!(x.iter().all(|v| (0.0..=1.0).contains(v)));
        }
        let dual = calibrate(&sim, None, None, Calibration::DualSoftmax { tau }).unwrap();
        prop_assert!(dual.data.iter().all(|v| v.is_finite() && (0.0..=1.0 + 1e-6).contains(v)));
    }

    /// Noisy-AND in odds form: O(p_f) = O(p_img) O(p_geo) / O(pi) (paper eq. 6).
    #[test]
    fn noisy_and_is_the_odds_product(
        x in 0.001f32..0.999,
        y in 0.001f32..0.999,
        prior in 1e-6f64..0.5,
    ) {
        let odds = |p: f64| p / (1.0 - p);
        let pf = noisy_and(x, y, prior) as f64;
        let want = odds(x as f64) * odds(y as f64) / odds(prior);
        prop_assert!(pf > 0.0 && pf < 1.0 || want > 1e6);
        if pf < 0.999 {
            prop_assert!((odds(pf) - want).abs() <= 1e-3 * want, "{} vs {want}", odds(pf));
        }
    }

    /// PLY and XYZ writers and readers round-trip the points.
    #[test]
    fn readers_round_trip_their_writers(pts in prop::collection::vec(point(), 1..200)) {
        let cloud = PointCloud::from_points(pts.clone());
        let ply = cgenreg::io::ply::encode_ply(&cloud);
        let back = cgenreg::io::ply::parse_ply(Path::new("gen.ply"), &ply).unwrap();
        prop_assert_eq!(&back.points, &pts);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("gen.xyz");
        cgenreg::io::xyz::write_xyz(&p, &cloud).unwrap();
        let back = cgenreg::io::xyz::read_xyz(&p).unwrap();
        prop_assert_eq!(back.points.len(), pts.len());
        for (a, b) in back.points.iter().zip(&pts) {
            prop_assert!((a - b).norm() <= 1e-5 * (1.0 + b.coords.norm()));
        }
    }

    /// gt.log: what format_gt_log writes, parse_gt_log reads back (target, source, pose).
    #[test]
    fn gt_log_round_trip(t in pose(), i in 0usize..60, j in 0usize..60) {
        let e = cgenreg::io::gtlog::GtEntry {
            target: i,
            source: j,
            n_fragments: 60,
            target_from_source: t,
        };
        let text = cgenreg::io::gtlog::format_gt_log(std::slice::from_ref(&e));
        let back = cgenreg::io::gtlog::parse_gt_log(Path::new("gen.log"), &text).unwrap();
        prop_assert_eq!(back.len(), 1);
        prop_assert_eq!((back[0].target, back[0].source), (i, j));
        let p = Point3::from(Vector3::new(1.0, -2.0, 0.5));
        prop_assert!((back[0].target_from_source * p - t * p).norm() < 1e-6);
    }
}
