//! Plausible bad or unusual inputs through the pipeline: scans too small to register are
//! refused naming the side and the file; a PCL-style cloud with NaN rows and a far outlier
//! registers like the clean cloud, with both reported in the result.

use cgenreg::dataset::pair_from_files;
use cgenreg::geometry::PointCloud;
use cgenreg::pipeline::{RegisterParams, Registration};
use nalgebra::Point3;
use std::path::Path;

fn write_xyz(p: &Path, pts: &[[f32; 3]]) {
    let s: String = pts
        .iter()
        .map(|q| format!("{} {} {}\n", q[0], q[1], q[2]))
        .collect();
    std::fs::write(p, s).unwrap();
}

/// A 12 x 12 x 12 grid with 4 cm spacing, jittered: enough keypoints at a 5 cm voxel.
fn block() -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for i in 0..12 {
        for j in 0..12 {
            for k in 0..12 {
                let jit = ((i * 7 + j * 13 + k * 29) % 11) as f32 * 1e-3;
                v.push([
                    i as f32 * 0.04 + jit,
                    j as f32 * 0.04,
                    k as f32 * 0.04 - jit,
                ]);
            }
        }
    }
    v
}

/// 1, 2 and 3-point scans (and collinear ones) on either side: the error names the side and
/// its file, never the other side ("the target points are identical" for a 3-point source).
#[test]
fn too_small_scans_are_named_by_side_and_file() {
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.xyz");
    write_xyz(&big, &block());
    let smalls: [&[[f32; 3]]; 4] = [
        &[[0.0, 0.0, 0.0]],
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        &[
            [0.0, 0.0, 0.0],
            [0.5, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.5, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [2.5, 0.0, 0.0],
        ],
    ];
    for (k, pts) in smalls.iter().enumerate() {
        let small = dir.path().join(format!("small{k}.xyz"));
        write_xyz(&small, pts);
        for (side, src, tgt) in [("source", &small, &big), ("target", &big, &small)] {
            let pair = pair_from_files(src, tgt, None).unwrap();
            let e = Registration::new(&RegisterParams::default())
                .run(&pair)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("the {side} ")) && e.contains(&format!("small{k}.xyz")),
                "{side} with {} points: {e}",
                pts.len()
            );
            let other = if side == "source" { "target" } else { "source" };
            assert!(!e.contains(&format!("the {other} ")), "{e}");
        }
    }
}

/// GeoTransformer's demo pair (cloud_bin_6 onto cloud_bin_0, exact GT) with the target
/// written as an organised PCL cloud: NaN rows in between and one point at -1e30. The NaN
/// rows are dropped and counted, the outlier reported, the target keypoints are those of the
/// clean cloud plus the outlier's own, and the pair registers as well as the clean one.
#[test]
fn nan_rows_and_a_far_outlier_are_reported_and_change_nothing() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let d = root.join("3dmatch-redkitchen/geotransformer-demo");
    let clean = pair_from_files(
        &d.join("src.npy"),
        &d.join("ref.npy"),
        Some(&d.join("gt.npy")),
    )
    .unwrap();
    let mut pts = clean.target.cloud.points.clone();
    let n = pts.len();
    for i in (0..n).step_by(97).rev() {
        pts.insert(i, Point3::new(f32::NAN, f32::NAN, f32::NAN));
    }
    pts.insert(n / 2, Point3::new(-1e30, 0.0, 0.0));
    let nans = pts.iter().filter(|p| p.x.is_nan()).count();
    let dir = tempfile::tempdir().unwrap();
    let tgt = dir.path().join("ref_organised.pcd");
    std::fs::write(
        &tgt,
        cgenreg::io::pcd::encode_pcd(&PointCloud::from_points(pts), "binary"),
    )
    .unwrap();
    let dirty = pair_from_files(&d.join("src.npy"), &tgt, Some(&d.join("gt.npy"))).unwrap();
    assert_eq!(dirty.target.cloud.len(), n + 1);
    let p = RegisterParams::default();
    let a = Registration::new(&p).run(&clean).unwrap();
    let b = Registration::new(&p).run(&dirty).unwrap();
    let w = b.warnings.join("\n");
    assert!(
        w.contains(&format!("{nans} of {} points", nans + n + 1)) && w.contains("NaN"),
        "{w}"
    );
    assert!(
        w.contains("1 far outlier") && w.contains("ref_organised.pcd"),
        "{w}"
    );
    assert_eq!(b.n_target_keypoints, a.n_target_keypoints + 1);
    // a real pair that registers gets no estimate warning
    for r in [&a, &b] {
        assert!(
            !r.warnings
                .iter()
                .any(|w| w.contains("no rigid") || w.contains("too few")),
            "{:?}",
            r.warnings
        );
    }
    // both register (RRE ≤ 15°, RTE ≤ 30 cm), to the same pose within 0.5° / 2 cm
    let (ma, mb) = (a.metrics.unwrap(), b.metrics.unwrap());
    assert!(ma.success && mb.success, "{ma:?} {mb:?}");
    assert!(
        (ma.rre_deg - mb.rre_deg).abs() < 0.5 && (ma.rte_m - mb.rte_m).abs() < 0.02,
        "{ma:?} {mb:?}"
    );
}

/// GeoTransformer's demo source against its own mirror image (x negated): the result warns
/// that no rigid transform explains the correspondences.
#[test]
fn a_cloud_against_its_mirror_image_is_flagged() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let src = root.join("3dmatch-redkitchen/geotransformer-demo/src.npy");
    let c = cgenreg::io::cloud::load_cloud(&src).unwrap();
    let mirrored: Vec<Point3<f32>> = c
        .points
        .iter()
        .map(|p| Point3::new(-p.x, p.y, p.z))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("mirror.ply");
    cgenreg::io::ply::write_ply(&m, &PointCloud::from_points(mirrored)).unwrap();
    let pair = pair_from_files(&src, &m, None).unwrap();
    let r = Registration::new(&RegisterParams::default())
        .run(&pair)
        .unwrap();
    assert!(
        r.warnings
            .iter()
            .any(|w| w.contains("no rigid transform") && w.contains("mirror")),
        "{:?}",
        r.warnings
    );
}

/// The command line's exit status tells "called wrongly" (2, as for what the parser refuses)
/// from "failed" (1): a flag that needs another one and a value out of range are 2, a missing
/// input file is 1, and the message says which.
#[test]
fn command_line_mistakes_exit_with_2_and_failures_with_1() {
    let dir = tempfile::tempdir().unwrap();
    let xyz = dir.path().join("a.xyz");
    write_xyz(&xyz, &block());
    let run = |args: &[&std::ffi::OsStr]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_cgenreg"))
            .args(args)
            .output()
            .unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let s = xyz.as_os_str();
    // a flag that needs another one (the library's usage error)
    let (code, err) = run(&[
        "register".as_ref(),
        "--source".as_ref(),
        s,
        "--target".as_ref(),
        s,
        "--wfm".as_ref(),
        "cached".as_ref(),
    ]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--wfm cached needs --wfm-dir"), "{err}");
    // a value out of range, checked by the library (not the parser)
    let (code, err) = run(&[
        "screenshot".as_ref(),
        "--panel".as_ref(),
        "no-such-panel".as_ref(),
        "--out".as_ref(),
        dir.path().join("x.png").as_os_str(),
    ]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("invalid parameter: --panel"), "{err}");
    // what the parser refuses: the same status
    let (code, err) = run(&["register".as_ref(), "--no-such-flag".as_ref()]);
    assert_eq!(code, Some(2), "{err}");
    // a failure: the input file is not there
    let missing = dir.path().join("missing.ply");
    let (code, err) = run(&[
        "register".as_ref(),
        "--source".as_ref(),
        missing.as_os_str(),
        "--target".as_ref(),
        s,
    ]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("missing.ply"), "{err}");
    assert!(!dir.path().join("x.png").exists());
}
