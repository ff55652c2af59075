//! `cgenreg dataset 3dmatch|kitti` on the official layouts, laid out at test time from the shared
//! data by symbolic links: the redkitchen part of 3DMatch / 3DLoMatch as Predator and the
//! 3DMatch toolbox lay it out, and the KITTI 07 scans as an odometry sequence.

use cgenreg::dataset::official::{kitti_manifest, threedmatch_manifest, KittiOptions, KittiRule};
use cgenreg::dataset::Dataset;
use nalgebra::Matrix4;
use std::os::unix::fs::symlink;
use std::path::{Path, PathBuf};
use std::process::Command;

const SCENE: &str = "7-scenes-redkitchen";

/// (fragments folder, benchmark folder) of the shared data, or None to skip.
fn redkitchen() -> Option<(PathBuf, PathBuf)> {
    let root = cgenreg::testing::test_data_root()?;
    let frags = cgenreg::testing::require_file(&root, "3dmatch-redkitchen-full/cloud_bin_59.pth")?;
    let bench =
        cgenreg::testing::require_file(&root, "3dmatch-redkitchen/benchmark/3DLoMatch/gt.info")?;
    Some((
        frags.parent()?.to_path_buf(),
        bench.parent()?.parent()?.to_path_buf(),
    ))
}

fn link_benchmark(bench: &Path, to: &Path) {
    for b in ["3DMatch", "3DLoMatch"] {
        let d = to.join(b).join(SCENE);
        std::fs::create_dir_all(&d).unwrap();
        for f in ["gt.log", "gt.info"] {
            symlink(bench.join(b).join(f), d.join(f)).unwrap();
        }
    }
}

fn gt_log_matrix(path: &Path, i: usize, j: usize) -> Matrix4<f64> {
    let e = cgenreg::io::gtlog::read_gt_log(path).unwrap();
    let e = e.iter().find(|e| e.target == i && e.source == j).unwrap();
    e.target_from_source.to_homogeneous()
}

/// Predator's layout (`ROOT/<scene>/cloud_bin_<k>.pth`, `ROOT/benchmarks/{3DMatch,3DLoMatch}/
/// <scene>/`): 506 3DMatch and 525 3DLoMatch pairs, each with its gt.log matrix and gt.info
/// entry, through the library and the command line; the benchmarks folder elsewhere through
/// `--benchmarks`.
#[test]
fn predator_layout_gives_the_whole_redkitchen_benchmark() {
    let Some((frags, bench)) = redkitchen() else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("3dmatch");
    std::fs::create_dir_all(&root).unwrap();
    symlink(&frags, root.join(SCENE)).unwrap();
    link_benchmark(&bench, &root.join("benchmarks"));
    let w = threedmatch_manifest(&root, None, None).unwrap();
    assert_eq!(
        w.pairs,
        [("3DMatch".to_string(), 506), ("3DLoMatch".to_string(), 525)]
    );
    assert_eq!(
        (w.fragments, w.scenes.as_slice()),
        (60, [SCENE.to_string()].as_slice())
    );
    // the 19 pairs both gt.logs list are in both splits, 3DLoMatch's copy through alias fragments
    assert!(w.text.contains("19 pair(s) listed in both"));

    let out = d.path().join("m.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .args(["dataset", "3dmatch"])
        .arg(&root)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        stdout.contains("3DMatch 506 pairs, 3DLoMatch 525 pairs")
            && stdout.contains("1031 pairs loaded back"),
        "{stdout}"
    );
    // never over an existing file without --force
    let again = Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .args(["dataset", "3dmatch"])
        .arg(&root)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));

    let ds = Dataset::load(&out).unwrap();
    assert_eq!(ds.pairs().len(), 1031);
    let lo = ds.pairs().iter().filter(|p| p.split == "3DLoMatch").count();
    assert_eq!(lo, 525);
    assert!(ds
        .pairs()
        .iter()
        .all(|p| p.scene.as_deref() == Some(SCENE) && p.gt_info.is_some()));
    // ids as the gt.log names them: target i, source j
    let p = ds.pair(&format!("{SCENE}/0-5")).unwrap();
    let gt = p.gt_target_from_source.unwrap().to_homogeneous();
    assert!((gt - gt_log_matrix(&bench.join("3DMatch/gt.log"), 0, 5)).amax() < 1e-7);
    let info = p.gt_info.as_ref().unwrap();
    assert_eq!((info.target, info.source), (0, 5));
    // a pair loads: the .pth fragments are read
    let pair = ds.load_pair(&format!("{SCENE}/0-5")).unwrap();
    assert!(pair.source.cloud.len() > 5000 && pair.target.cloud.len() > 5000);

    // the benchmarks folder elsewhere
    let root2 = d.path().join("frags-only");
    std::fs::create_dir_all(&root2).unwrap();
    symlink(&frags, root2.join(SCENE)).unwrap();
    let elsewhere = d.path().join("configs/benchmarks");
    link_benchmark(&bench, &elsewhere);
    let w2 = threedmatch_manifest(&root2, Some(&elsewhere), None).unwrap();
    assert_eq!(w2.pairs, w.pairs);
}

/// The 3DMatch toolbox's layout (`ROOT/<scene>/cloud_bin_<k>.ply`, `ROOT/<scene>-evaluation/`):
/// the 3DMatch pairs, PLY preferred where both a PLY and a .pth are present; an incomplete
/// download is an error naming the missing file.
#[test]
fn toolbox_layout_and_incomplete_downloads() {
    let Some((frags, bench)) = redkitchen() else {
        return;
    };
    let data = frags.parent().unwrap();
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("toolbox");
    let scene = root.join(SCENE);
    let eval = root.join(format!("{SCENE}-evaluation"));
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::create_dir_all(&eval).unwrap();
    for k in 0..60 {
        let f = format!("cloud_bin_{k}.pth");
        symlink(frags.join(&f), scene.join(&f)).unwrap();
    }
    for k in [0, 4] {
        let f = format!("cloud_bin_{k}.ply");
        symlink(
            data.join("3dmatch-redkitchen/teaser-plusplus").join(&f),
            scene.join(&f),
        )
        .unwrap();
    }
    symlink(bench.join("3DMatch/gt.log"), eval.join("gt.log")).unwrap();
    // gt.info missing: named
    let e = threedmatch_manifest(&root, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("gt.info") && e.contains(&format!("{SCENE}-evaluation")),
        "{e}"
    );
    symlink(bench.join("3DMatch/gt.info"), eval.join("gt.info")).unwrap();
    let w = threedmatch_manifest(&root, None, None).unwrap();
    assert_eq!(w.pairs, [("3DMatch".to_string(), 506)]);
    assert!(w
        .text
        .contains("cloud = \"7-scenes-redkitchen/cloud_bin_0.ply\""));
    assert!(w
        .text
        .contains("cloud = \"7-scenes-redkitchen/cloud_bin_1.pth\""));
    assert!(
        w.text.contains("allow_outside_root = true"),
        "symbolic links lead outside"
    );
    // a fragment missing: named, with the gt.log entry that needs it
    std::fs::remove_file(scene.join("cloud_bin_1.pth")).unwrap();
    let e = threedmatch_manifest(&root, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cloud_bin_1.ply") && e.contains("entry `0 1`"),
        "{e}"
    );
    // not a 3DMatch folder at all
    let e = threedmatch_manifest(&scene, None, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("-evaluation") && e.contains("benchmarks"), "{e}");
}

/// The KITTI 07 scans laid out as an odometry sequence (`sequences/07/velodyne/NNNNNN.bin` for
/// frames 10, 25, 41, 56, 71, `calib.txt` with the sequence's published Tr, `poses/07.txt`):
/// every pair >= 10 m apart with the ground truth of the data's own gt_pairs.txt (inverted:
/// the later scan is the target here, as in the published pairs); the published rule, which
/// walks consecutive scans, finds none and says why; a missing calib.txt is named.
#[test]
fn kitti_sequence_layout() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let Some(gt_pairs) = cgenreg::testing::require_file(&data, "kitti07-lidar/gt_pairs.txt") else {
        return;
    };
    let k07 = gt_pairs.parent().unwrap();
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("dataset");
    let seq = root.join("sequences/07");
    std::fs::create_dir_all(seq.join("velodyne")).unwrap();
    std::fs::create_dir_all(root.join("poses")).unwrap();
    let frames = [10usize, 25, 41, 56, 71];
    for (i, f) in frames.iter().enumerate() {
        symlink(
            k07.join(format!("keyframe-{i}.bin")),
            seq.join(format!("velodyne/{f:06}.bin")),
        )
        .unwrap();
    }
    // the official poses file has 12 numbers a line; the shared copy has a timestamp first
    let poses: String = std::fs::read_to_string(k07.join("poses-07.txt"))
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().skip(1).collect::<Vec<_>>().join(" ") + "\n")
        .collect();
    std::fs::write(root.join("poses/07.txt"), poses).unwrap();
    let o = KittiOptions {
        sequences: vec![7],
        min_distance_m: 10.0,
        rule: KittiRule::All,
        fields: Some(3),
    };
    let e = kitti_manifest(&root, &o).unwrap_err().to_string();
    assert!(e.contains("calib.txt"), "{e}");
    // the published Velodyne-to-camera-0 calibration of sequences 04-10 (the data's MANIFEST)
    std::fs::write(
        seq.join("calib.txt"),
        "P0: 7.1e+02 0 6.0e+02 0 0 7.1e+02 1.8e+02 0 0 0 1 0\n\
         Tr: -1.857739385241e-03 -9.999659513510e-01 -8.039975204516e-03 -4.784029760483e-03 \
         -6.481465826011e-03 8.051860151134e-03 -9.999466081774e-01 -7.337429464231e-02 \
         9.999773098287e-01 -1.805528627661e-03 -6.496203536139e-03 -3.339968064433e-01\n",
    )
    .unwrap();
    let w = kitti_manifest(&root, &o).unwrap();
    assert_eq!(w.pairs, [("KITTI".to_string(), 6)]);
    let m = d.path().join("kitti.toml");
    std::fs::write(&m, &w.text).unwrap();
    let ds = Dataset::load(&m).unwrap();
    // gt_pairs.txt: blocks "target source distance rotation" + 4 rows, keyframe numbers
    let text = std::fs::read_to_string(&gt_pairs).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    let mut checked = 0;
    for b in lines.chunks(5) {
        let h: Vec<&str> = b[0].split_whitespace().collect();
        let (t, s): (usize, usize) = (h[0].parse().unwrap(), h[1].parse().unwrap());
        let m: Vec<f64> = b[1..]
            .iter()
            .flat_map(|l| l.split_whitespace())
            .map(|x| x.parse().unwrap())
            .collect();
        let theirs = Matrix4::from_row_slice(&m);
        let id = format!("kitti/07_{:06}-07_{:06}", frames[s], frames[t]);
        if let Some(p) = ds.pair(&id) {
            let ours = p.gt_target_from_source.unwrap().to_homogeneous();
            let inv = theirs.try_inverse().unwrap();
            assert!((ours - inv).amax() < 1e-6, "{id}: {ours} vs {inv}");
            assert_eq!(p.scene.as_deref(), Some("07"));
            checked += 1;
        }
    }
    assert_eq!(checked, 6);
    assert!(w.text.contains("No ICP refinement"));
    let pair = ds
        .load_pair(&format!("kitti/07_{:06}-07_{:06}", 71, 56))
        .unwrap();
    assert_eq!(pair.target.cloud.len(), 19_872);
    let published = KittiOptions {
        rule: KittiRule::Published,
        ..o
    };
    let e = kitti_manifest(&root, &published).unwrap_err().to_string();
    assert!(e.contains("--rule all"), "{e}");
}
