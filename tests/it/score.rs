//! `cgenreg score`: another method's poses scored by the same formulas as `bench`, on the whole
//! redkitchen benchmark laid out as Predator does. Poses made from the official gt.log with known
//! errors separate the two recalls: a 25 cm translation error passes RTE <= 0.30 m but not the
//! official RMSE < 0.2 m; a 1 m error passes neither. (A rotation is no such probe: the RMSE
//! weighs it by the fragment's extent about the source origin, so a 20° turn can pass it.)

use nalgebra::{Isometry3, Translation3};
use std::os::unix::fs::symlink;
use std::path::{Path, PathBuf};
use std::process::Command;

const SCENE: &str = "7-scenes-redkitchen";

/// The whole-redkitchen manifest, written by `cgenreg dataset 3dmatch` into `dir`.
fn manifest(dir: &Path) -> Option<PathBuf> {
    let root = cgenreg::testing::test_data_root()?;
    let frags = cgenreg::testing::require_file(&root, "3dmatch-redkitchen-full/cloud_bin_59.pth")?;
    let bench =
        cgenreg::testing::require_file(&root, "3dmatch-redkitchen/benchmark/3DLoMatch/gt.info")?;
    let bench = bench.parent()?.parent()?.to_path_buf();
    let layout = dir.join("layout");
    std::fs::create_dir_all(&layout).unwrap();
    symlink(frags.parent()?, layout.join(SCENE)).unwrap();
    for b in ["3DMatch", "3DLoMatch"] {
        let d = layout.join("benchmarks").join(b).join(SCENE);
        std::fs::create_dir_all(&d).unwrap();
        for f in ["gt.log", "gt.info"] {
            symlink(bench.join(b).join(f), d.join(f)).unwrap();
        }
    }
    let m = dir.join("m.toml");
    let w = cgenreg::dataset::official::threedmatch_manifest(&layout, None, None).unwrap();
    std::fs::write(&m, w.text).unwrap();
    Some(m)
}

fn rows(t: &Isometry3<f64>) -> serde_json::Value {
    let h = t.to_homogeneous();
    serde_json::json!((0..4)
        .map(|i| (0..4).map(|j| h[(i, j)]).collect::<Vec<f64>>())
        .collect::<Vec<_>>())
}

fn score(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .arg("score")
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn score_judges_given_poses_as_bench_does() {
    let d = tempfile::tempdir().unwrap();
    let Some(m) = manifest(d.path()) else {
        return;
    };
    let ds = cgenreg::dataset::Dataset::load(&m).unwrap();
    // pair k of the 3DMatch split: exact (k % 4 == 0), 25 cm off along x (1), 1 m off along y
    // (2), no pose (3); 3DLoMatch pairs are left out of the file (scored as failures)
    let mut pairs = Vec::new();
    let mut expect = [0usize; 4];
    let mut counted = [0usize; 4];
    for (k, p) in ds
        .pairs()
        .iter()
        .filter(|p| p.split == "3DMatch")
        .enumerate()
    {
        let gt = p.gt_target_from_source.unwrap();
        let est = match k % 4 {
            0 => Some(gt),
            1 => Some(Translation3::new(0.25, 0.0, 0.0) * gt),
            2 => Some(Translation3::new(0.0, 1.0, 0.0) * gt),
            _ => None,
        };
        expect[k % 4] += 1;
        if p.gt_info
            .as_ref()
            .is_some_and(|i| i.source.abs_diff(i.target) > 1)
        {
            counted[k % 4] += 1;
        }
        pairs.push(serde_json::json!({
            "id": p.id,
            "target_from_source": est.as_ref().map(rows),
            "time_s": 0.5,
        }));
    }
    let poses = d.path().join("poses.json");
    let file = serde_json::json!({"runs": [{"method": "a test method", "pairs": pairs}]});
    std::fs::write(&poses, serde_json::to_vec(&file).unwrap()).unwrap();
    let out = d.path().join("scored.json");
    let o = score(&[
        m.as_os_str(),
        poses.as_os_str(),
        "--json".as_ref(),
        out.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("a test method"), "{stdout}");
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("525 of 1031 pairs are not in"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let run: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let field = run["field"].as_array().unwrap();
    let pooled = |b: &str| {
        field
            .iter()
            .find(|r| r["benchmark"] == b && r.get("scene").is_none())
            .unwrap()
            .clone()
    };
    let m3 = pooled("3DMatch");
    assert_eq!(m3["pairs"], 506);
    // exact and 25 cm register under 15° / 0.30 m; 1 m and no pose do not
    assert_eq!(m3["registered"], expect[0] + expect[1]);
    // the official recall: only the exact poses (RMSE 0 < 0.2 m; 25 cm is not)
    assert_eq!(m3["rmse_pairs"], counted.iter().sum::<usize>());
    let official = m3["rmse_recall"].as_f64().unwrap();
    let want = counted[0] as f64 / counted.iter().sum::<usize>() as f64;
    assert!((official - want).abs() < 1e-12, "{official} vs {want}");
    // mean TE over the registered pairs: half at 0, half at 25 cm
    let te = m3["te_mean_m"].as_f64().unwrap();
    let want_te = 0.25 * expect[1] as f64 / (expect[0] + expect[1]) as f64;
    assert!((te - want_te).abs() < 1e-6, "{te} vs {want_te}");
    let lo = pooled("3DLoMatch");
    assert_eq!(
        (lo["pairs"].as_u64(), lo["registered"].as_u64()),
        (Some(525), Some(0))
    );
    // a run file `diff` reads: itself against itself flips nothing
    let o = Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .args(["diff".as_ref(), out.as_os_str(), out.as_os_str()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn score_names_the_pair_and_field_of_a_bad_pose() {
    let d = tempfile::tempdir().unwrap();
    let Some(m) = manifest(d.path()) else {
        return;
    };
    let poses = d.path().join("poses.json");
    let scaled = [
        [2.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let id = format!("{SCENE}/0-1");
    for (body, says) in [
        (
            serde_json::json!({"pairs": [{"id": id, "target_from_source": scaled}]}),
            vec!["0-1", "target_from_source", "not a rotation"],
        ),
        (
            serde_json::json!({"pairs": [{"id": id, "target_from_source": [[1.0, 0.0]]}]}),
            vec!["0-1", "target_from_source", "4x4"],
        ),
        (
            serde_json::json!({"runs": [{"method": "a", "pairs": []}, {"method": "b", "pairs": []}]}),
            vec!["--run", "0: a", "1: b"],
        ),
        (
            serde_json::json!({"pairs": [{"id": "elsewhere/1-2", "target_from_source": null}]}),
            vec!["none of the 1031 selected pairs"],
        ),
        (serde_json::json!([1, 2]), vec!["expected `pairs`"]),
    ] {
        std::fs::write(&poses, serde_json::to_vec(&body).unwrap()).unwrap();
        let o = score(&[m.as_os_str(), poses.as_os_str()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{body}: accepted");
        assert!(err.contains("poses.json"), "{err}");
        for s in says {
            assert!(err.contains(s), "{body}: {err} lacks {s}");
        }
    }
}
