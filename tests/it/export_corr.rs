//! `register --export-corr` and the ground-truth convention guard on a real staged pair
//! (GeoTransformer's 3DMatch demo: 7-scenes-redkitchen cloud_bin_6 onto cloud_bin_0; skipped
//! when the data is missing, failing under CI=true), and the inspector's export through the
//! worker (the same library function).

use cgenreg::io::npy::read_npz;
use nalgebra::{Isometry3, Matrix4, Point3};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn demo_dir() -> Option<PathBuf> {
    Some(cgenreg::testing::test_data_root()?.join("3dmatch-redkitchen/geotransformer-demo"))
}

fn register(d: &Path, gt: &Path, export: Option<&Path>) -> Value {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cgenreg"));
    c.env_remove("CGENREG_CACHE").args([
        "register",
        "--source",
        d.join("src.npy").to_str().unwrap(),
        "--target",
        d.join("ref.npy").to_str().unwrap(),
        "--gt",
        gt.to_str().unwrap(),
        "--json",
    ]);
    if let Some(e) = export {
        c.arg("--export-corr").arg(e);
    }
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "register failed: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

fn iso(rows: &Value) -> Isometry3<f64> {
    let v: Vec<f64> = rows
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect();
    cgenreg::geometry::transform::isometry_from_matrix(&Matrix4::from_row_slice(&v)).unwrap()
}

fn pts(a: &[f64]) -> Vec<Point3<f64>> {
    a.chunks_exact(3)
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect()
}

#[test]
fn export_reads_back_and_the_flags_agree_with_the_transforms() {
    let Some(d) = demo_dir() else { return };
    let dir = tempfile::tempdir().unwrap();
    let npz = dir.path().join("corr.npz");
    let res = register(&d, &d.join("gt.npy"), Some(&npz));
    let n = res["n_correspondences"].as_u64().unwrap() as usize;
    assert!(n > 100, "{n}");

    // a valid zip whose members are the documented arrays plus meta.json
    let f = std::fs::File::open(&npz).unwrap();
    let mut zip = zip::ZipArchive::new(f).unwrap();
    let names: Vec<String> = zip.file_names().map(String::from).collect();
    assert!(names.contains(&"meta.json".to_string()), "{names:?}");
    let meta: Value = {
        use std::io::Read;
        let mut s = String::new();
        zip.by_name("meta.json")
            .unwrap()
            .read_to_string(&mut s)
            .unwrap();
        serde_json::from_str(&s).unwrap()
    };
    assert_eq!(meta["n_correspondences"].as_u64(), Some(n as u64));
    let thr = meta["inlier_threshold_m"].as_f64().unwrap();
    assert_eq!(thr, 0.10);
    assert!(meta["code_version"]
        .as_str()
        .unwrap()
        .starts_with("cgenreg"));
    assert_eq!(meta["params"]["voxel"].as_f64(), Some(0.05));

    // read back with the project's own NPZ reader
    let m = read_npz(&npz).unwrap();
    for k in [
        "src_idx",
        "tgt_idx",
        "fused",
        "p_img",
        "p_geo",
        "branch",
        "inlier_est",
        "inlier_gt",
        "kept_by_estimator",
    ] {
        assert_eq!(m[k].shape, vec![n], "{k}");
    }
    assert_eq!(m["src_xyz"].shape, vec![n, 3]);
    let est = iso(&res["target_from_source"]);
    let gt = iso(&res["gt_target_from_source"]);
    let file_est = m["target_from_source"].to_f64();
    let json_est: Vec<f64> = res["target_from_source"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect();
    // (serde_json's float parsing may be 1 ulp off)
    assert!(
        file_est
            .iter()
            .zip(&json_est)
            .all(|(a, b)| (a - b).abs() <= 1e-12),
        "the file's estimate {file_est:?} is not the JSON's {json_est:?}"
    );
    let (s, t) = (pts(&m["src_xyz"].to_f64()), pts(&m["tgt_xyz"].to_f64()));
    let (ie, ig) = (m["inlier_est"].to_f64(), m["inlier_gt"].to_f64());
    let mut est_in = 0;
    let mut gt_in = 0;
    for i in 0..n {
        let re = (est * s[i] - t[i]).norm();
        let rg = (gt * s[i] - t[i]).norm();
        // flags agree with the residuals (away from the threshold's rounding)
        if (re - thr).abs() > 1e-6 {
            assert_eq!(ie[i] == 1.0, re < thr, "estimate flag {i}: {re}");
        }
        if (rg - thr).abs() > 1e-6 {
            assert_eq!(ig[i] == 1.0, rg < thr, "GT flag {i}: {rg}");
        }
        est_in += (ie[i] == 1.0) as usize;
        gt_in += (ig[i] == 1.0) as usize;
    }
    assert!(est_in > 10 && gt_in > 10, "{est_in} {gt_in}");
    // geometry only: no image posterior; every match is the geometric branch's proposal or the
    // fused score's (geometry only: the same), indices into the keypoints
    assert!(m["p_img"].to_f64().iter().all(|x| x.is_nan()));
    let pg = m["p_geo"].to_f64();
    assert!(pg.iter().all(|x| (0.0..=1.0).contains(x)));
    // geometry only: the fused score is the geometric posterior, recomputed row by row
    let fused = m["fused"].to_f64();
    for (f, g) in fused.iter().zip(&pg) {
        assert!(
            (f - g).abs() <= 1e-6 * f.abs().max(1e-30),
            "fused {f} vs p_geo {g}"
        );
    }
    assert!(m["branch"].to_f64().iter().all(|&b| b == 2.0));
    let nsk = res["n_source_keypoints"].as_f64().unwrap();
    assert!(m["src_idx"].to_f64().iter().all(|&i| i >= 0.0 && i < nsk));
    let kept = m["kept_by_estimator"].to_f64();
    assert_eq!(
        kept.iter().filter(|&&k| k == 1.0).count() as u64,
        res["n_inliers"].as_u64().unwrap()
    );

    // NumPy reads it too, where it is installed
    let has_numpy = Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if has_numpy {
        let script = format!(
            "import numpy as np, json\nz = np.load({:?})\nassert z['src_idx'].shape == ({n},)\n\
             assert z['src_xyz'].shape == ({n}, 3)\nm = json.loads(bytes(z['meta.json']))\n\
             assert m['n_correspondences'] == {n}\nprint(int(z['inlier_gt'].sum()))\n",
            npz.to_str().unwrap()
        );
        let o = Command::new("python3")
            .args(["-c", &script])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let py_gt_in: usize = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
        assert_eq!(py_gt_in, gt_in);
    } else {
        eprintln!("python3 with numpy not found: NumPy read-back skipped");
    }

    // the right GT: no convention warning
    let c = &res["convention"];
    assert_eq!(c["inverse_explains_better"], Value::Bool(false), "{c}");
    assert!(c["overlap_gt"].as_f64().unwrap() > c["overlap_inverse"].as_f64().unwrap());
}

#[test]
fn inverted_ground_truth_fires_the_convention_warning() {
    let Some(d) = demo_dir() else { return };
    let gt = cgenreg::io::npy::read_npy_matrix4(&d.join("gt.npy")).unwrap();
    let inv = gt.inverse().to_homogeneous();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("gt_inverted.txt");
    let text: String = (0..4)
        .map(|r| {
            (0..4)
                .map(|c| format!("{:.17e}", inv[(r, c)]))
                .collect::<Vec<_>>()
                .join(" ")
                + "\n"
        })
        .collect();
    std::fs::write(&p, text).unwrap();
    let res = register(&d, &p, None);
    let c = &res["convention"];
    assert_eq!(c["inverse_explains_better"], Value::Bool(true), "{c}");
    let w = c["warning"].as_str().unwrap();
    assert!(w.contains("inverse"), "{w}");
    assert!(res["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .any(|x| x.as_str() == Some(w)));
}

/// The inspector's "Export correspondences..." goes through the worker to the same library
/// function: the file it writes equals the CLI's table for the same pair and settings.
#[cfg(feature = "gui")]
#[test]
fn worker_export_matches_the_cli() {
    use cgenreg::app::worker::PipelineWorker;
    use cgenreg::dataset::manifest::Dataset;
    let Some(d) = demo_dir() else { return };
    let ds = Dataset::from_two_files(
        &d.join("src.npy"),
        &d.join("ref.npy"),
        Some(&d.join("gt.npy")),
    )
    .unwrap();
    // the CLI's geometry-only defaults: row nearest neighbours
    let mut params = cgenreg::pipeline::RegisterParams::default();
    params.fusion.selection = cgenreg::fusion::select::Selection::RowNn;
    let mut w = PipelineWorker::new(ds, params);
    w.set_cache(None);
    let id = w.pair_ids()[0].clone();
    let model = w.run_pair(&id).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("gui.npz");
    let n = w.export_correspondences(&a).unwrap();
    assert_eq!(n, model.matches.len());
    let b = dir.path().join("cli.npz");
    register(&d, &d.join("gt.npy"), Some(&b));
    let (ma, mb) = (read_npz(&a).unwrap(), read_npz(&b).unwrap());
    for k in ["src_idx", "tgt_idx", "fused", "inlier_gt", "branch"] {
        assert!(
            ma[k] == mb[k],
            "{k}: the worker's {:?} vs the CLI's {:?}",
            ma[k].shape,
            mb[k].shape
        );
    }
}
