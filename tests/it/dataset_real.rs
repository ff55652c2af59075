//! Dataset tests on the staged real data (skipped when it is missing, failing under CI=true).

use cgenreg::camera::camera_txt::read_numbers;
use cgenreg::dataset::fragment::{build_fragment, CropBox, FRAGMENT_LEN};
use cgenreg::dataset::rgbd_sequence::RgbdSequence;
use cgenreg::dataset::{pair_from_files, Dataset};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix4, Point3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Fraction of `query` points whose nearest neighbour in `reference` is within `radius`.
fn fraction_within(query: &[Point3<f32>], reference: &[Point3<f32>], radius: f32) -> f64 {
    let pts: Vec<[f32; 3]> = reference.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree = ImmutableKdTree::new_from_slice(&pts).unwrap();
    let hits = query
        .par_iter()
        .filter(|q| {
            let nn = tree
                .query(&[q.x, q.y, q.z])
                .nearest_one::<SquaredEuclidean<f32>>()
                .execute();
            nn.distance <= radius * radius
        })
        .count();
    hits as f64 / query.len().max(1) as f64
}

#[test]
fn fraction_within_matches_brute_force() {
    let mut s = cgenreg::testing::Lcg(7);
    let mut rnd = || s.unit_f32();
    let a: Vec<Point3<f32>> = (0..800).map(|_| Point3::new(rnd(), rnd(), rnd())).collect();
    let b: Vec<Point3<f32>> = (0..900).map(|_| Point3::new(rnd(), rnd(), rnd())).collect();
    let r = 0.05f32;
    let brute = a
        .iter()
        .filter(|q| b.iter().any(|p| (p - *q).norm_squared() <= r * r))
        .count() as f64
        / a.len() as f64;
    assert!(brute > 0.05 && brute < 0.95, "{brute}");
    assert_eq!(fraction_within(&a, &b, r), brute);
}

fn manifest(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/manifests")
        .join(name)
}

#[test]
fn rebuilt_fragments_agree_with_staged_3dmatch() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let seq = RgbdSequence::open(&root.join("7scenes-redkitchen-rgbd")).unwrap();
    let staged = [
        (0, "3dmatch-redkitchen/teaser-plusplus/cloud_bin_0.ply"),
        (
            5,
            "3dmatch-redkitchen/dip/threed_match_7-scenes-redkitchen_cloud_bin_5.ply",
        ),
    ];
    for (k, file) in staged {
        let t = std::time::Instant::now();
        let frag =
            build_fragment(&seq, FRAGMENT_LEN * k, FRAGMENT_LEN, 0.01, format!("{k}")).unwrap();
        let dt = t.elapsed();
        let fs = frag.frames.as_ref().unwrap();
        assert_eq!(fs.frames.len(), 50);
        assert_eq!(fs.frames[0].index, 50 * k);
        assert!(fs.frames[0].scan_from_camera.translation.vector.norm() < 1e-9);
        assert!(fs.frames[49].scan_from_camera.translation.vector.norm() > 1e-3);
        let reference = cgenreg::io::cloud::load_cloud(&root.join(file)).unwrap();
        let inside: Vec<_> = frag
            .cloud
            .points
            .iter()
            .copied()
            .filter(|p| CropBox::THREEDMATCH.contains(p))
            .collect();
        let staged_to_rebuilt = fraction_within(&reference.points, &frag.cloud.points, 0.02);
        let rebuilt_to_staged = fraction_within(&inside, &reference.points, 0.02);
        println!(
            "fragment {k}: rebuilt {} points ({} in the 3DMatch box) in {dt:?}, staged {}; \
             staged within 2 cm of rebuilt {:.2} %, rebuilt (in box) within 2 cm of staged {:.2} %",
            frag.cloud.len(),
            inside.len(),
            reference.len(),
            100.0 * staged_to_rebuilt,
            100.0 * rebuilt_to_staged
        );
        assert!(staged_to_rebuilt >= 0.95, "{staged_to_rebuilt}");
        assert!(rebuilt_to_staged >= 0.85, "{rebuilt_to_staged}");
        // A wrong pose convention (P_f * inv(P_first)) or a wrong fragment would not agree.
        let other =
            cgenreg::io::cloud::load_cloud(&root.join(staged[(k == 0) as usize].1)).unwrap();
        assert!(fraction_within(&other.points, &frag.cloud.points, 0.02) < 0.5);
    }
}

#[test]
fn shipped_manifests_pairs_and_gt() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let staged = Dataset::load(&manifest("redkitchen-staged.toml")).unwrap();
    assert_eq!(staged.pairs_in_split("3DMatch").count(), 12);
    assert_eq!(staged.pairs_in_split("3DLoMatch").count(), 4);
    assert!(staged.pair("redkitchen/21-34").is_some());
    let rgbd = Dataset::load(&manifest("redkitchen-rgbd.toml")).unwrap();
    assert_eq!(rgbd.pairs_in_split("3DMatch").count(), 27);
    assert_eq!(rgbd.pairs_in_split("3DLoMatch").count(), 10);
    assert_eq!(rgbd.fragments().len(), 10);

    // gt.log `i j` == inv(P_50i) * P_50j from the raw pose files: the raw text matrices agree
    // to 1e-6; the manifests' isometries (rotations re-orthonormalised on reading, which moves
    // these 8-digit matrices by up to ~3e-5) agree with the re-orthonormalised poses to 1e-4.
    let seq = RgbdSequence::open(&root.join("7scenes-redkitchen-rgbd")).unwrap();
    let raw_pose = |k: usize| {
        let v = read_numbers(&root.join(format!("7scenes-redkitchen-rgbd/frame-{k:06}.pose.txt")))
            .unwrap();
        Matrix4::from_row_slice(&v)
    };
    let raw_log = |split: &str| -> Vec<(usize, usize, Matrix4<f64>)> {
        let v = read_numbers(&root.join(format!("3dmatch-redkitchen/benchmark/{split}/gt.log")))
            .unwrap();
        v.chunks(19)
            .map(|c| {
                (
                    c[0] as usize,
                    c[1] as usize,
                    Matrix4::from_row_slice(&c[3..]),
                )
            })
            .collect()
    };
    let logs = [
        ("3DMatch", raw_log("3DMatch")),
        ("3DLoMatch", raw_log("3DLoMatch")),
    ];
    let mut checked = 0;
    for ds in [&staged, &rgbd] {
        for p in ds.pairs() {
            let (i, j): (usize, usize) = (p.target.parse().unwrap(), p.source.parse().unwrap());
            if i >= 10 || j >= 10 {
                continue;
            }
            let log = &logs.iter().find(|(s, _)| *s == p.split).unwrap().1;
            let (_, _, m) = log.iter().find(|(a, b, _)| (*a, *b) == (i, j)).unwrap();
            let from_raw = raw_pose(50 * i).try_inverse().unwrap() * raw_pose(50 * j);
            let d_raw = (m - from_raw).amax();
            assert!(
                d_raw < 1e-6,
                "{}: raw gt.log differs from raw poses by {d_raw}",
                p.id
            );
            let from_poses = seq.world_from_camera(50 * i).unwrap().inverse()
                * seq.world_from_camera(50 * j).unwrap();
            let gt = p.gt_target_from_source.unwrap();
            let d = (gt.to_homogeneous() - from_poses.to_homogeneous()).amax();
            assert!(d < 1e-4, "{}: gt differs from the poses by {d}", p.id);
            checked += 1;
        }
    }
    assert_eq!(checked, 15 + 37);
}

#[test]
fn staged_pair_loads_with_frames_and_gt_aligns() {
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let ds = Dataset::load(&manifest("redkitchen-staged.toml")).unwrap();
    let pair = ds.load_pair("redkitchen/0-4").unwrap();
    assert_eq!(pair.target.cloud.len(), 258_342);
    assert_eq!(pair.source.cloud.len(), 313_395);
    assert_eq!(pair.source.frames.as_ref().unwrap().frames[0].index, 200);
    let gt = pair.gt_target_from_source.unwrap();
    let src_sub: Vec<_> = pair
        .source
        .cloud
        .points
        .iter()
        .step_by(10)
        .copied()
        .collect();
    let moved: Vec<_> = src_sub.iter().map(|p| gt.cast::<f32>() * p).collect();
    let with_gt = fraction_within(&moved, &pair.target.cloud.points, 0.0375);
    let without = fraction_within(&src_sub, &pair.target.cloud.points, 0.0375);
    println!("0-4: overlap at 3.75 cm: GT {with_gt:.3}, identity {without:.3}");
    assert!(
        with_gt > 0.3 && with_gt > 2.0 * without,
        "{with_gt} vs {without}"
    );
}

#[test]
fn rgbd_manifest_fragment_is_cropped_and_has_frames() {
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let ds = Dataset::load(&manifest("redkitchen-rgbd.toml")).unwrap();
    let s = ds.load_fragment("3").unwrap();
    assert!(s.cloud.len() > 100_000);
    assert!(s
        .cloud
        .points
        .iter()
        .all(|p| CropBox::THREEDMATCH.contains(p)));
    assert_eq!(s.frames.unwrap().frames.len(), 50);
}

#[test]
fn lidar_pair_from_files() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let d = root.join("small-gicp-lidar-pair");
    let pair = pair_from_files(
        &d.join("source.ply"),
        &d.join("target.ply"),
        Some(&d.join("T_target_source.txt")),
    )
    .unwrap();
    assert_eq!(pair.source.cloud.len(), 69_792);
    assert_eq!(pair.target.cloud.len(), 69_088);
    assert_eq!(pair.id, "files/target-source");
    assert!(
        pair.gt_target_from_source
            .unwrap()
            .translation
            .vector
            .norm()
            > 0.1
    );
    let e = pair_from_files(&d.join("nope.ply"), &d.join("target.ply"), None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.ply"), "{e}");
}

/// The development set (assets/manifests/redkitchen-dev.toml) is not the evaluated set: no
/// dev fragment has the frame range of an evaluated fragment, no dev pair is an evaluated
/// pair, every dev GT is inv(P_target_first) * P_source_first from the raw poses, and the
/// overlap rule that picked the dev pairs puts an evaluated 3DMatch pair above 30 % and an
/// evaluated 3DLoMatch pair in 10-30 % (the rule agrees with the official split).
#[test]
fn dev_manifest_is_disjoint_from_the_evaluated_pairs() {
    use cgenreg::dataset::manifest::FragmentSource;
    use cgenreg::metrics::overlap::pair_overlap;
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dev = Dataset::load(&manifest("redkitchen-dev.toml")).unwrap();
    let eval = Dataset::load(&manifest("redkitchen-rgbd.toml")).unwrap();
    let range = |ds: &Dataset, id: &str| match &ds.fragment(id).unwrap().source {
        FragmentSource::Rgbd { range, .. } => (range.dir.clone(), range.first, range.count),
        _ => panic!("{id}: not an RGB-D fragment"),
    };
    let eval_ranges: Vec<_> = eval
        .fragments()
        .iter()
        .map(|f| range(&eval, &f.id))
        .collect();
    assert_eq!(dev.fragments().len(), 9);
    for f in dev.fragments() {
        let r = range(&dev, &f.id);
        assert_eq!(r.1 % 50, 25, "{}", f.id);
        assert!(
            !eval_ranges.contains(&r),
            "{} is an evaluated fragment",
            f.id
        );
    }
    let seq = RgbdSequence::open(&eval_ranges[0].0).unwrap();
    let n_lo = dev.pairs_in_split("3DLoMatch-like").count();
    assert!(n_lo >= 8, "{n_lo} low-overlap dev pairs");
    assert_eq!(
        dev.pairs().len(),
        n_lo + dev.pairs_in_split("3DMatch-like").count()
    );
    for p in dev.pairs() {
        let (t, s) = (range(&dev, &p.target).1, range(&dev, &p.source).1);
        let from_poses =
            seq.world_from_camera(t).unwrap().inverse() * seq.world_from_camera(s).unwrap();
        let gt = p.gt_target_from_source.unwrap();
        assert!(
            (gt.to_homogeneous() - from_poses.to_homogeneous()).amax() < 1e-12,
            "{}",
            p.id
        );
        for e in eval.pairs() {
            let (et, es) = (range(&eval, &e.target).1, range(&eval, &e.source).1);
            assert!((et, es) != (t, s), "{} is evaluated pair {}", p.id, e.id);
        }
    }
    // The overlap rule on two evaluated pairs with their official split.
    for (id, lo, hi) in [
        ("redkitchen-rgbd/2-3", 0.3, 1.0),
        ("redkitchen-rgbd/3-7", 0.1, 0.3),
    ] {
        let pair = eval.load_pair(id).unwrap();
        let o = pair_overlap(
            &pair.source.cloud,
            &pair.target.cloud,
            &pair.gt_target_from_source.unwrap(),
        );
        println!("{id}: overlap {o:?}");
        assert!(o.max() > lo && o.max() <= hi, "{id}: {o:?}");
    }
}

/// The third round's development pairs: fragments at offsets 12 and 37 (neither an evaluated
/// boundary, 50k, nor the first development set's, 50k+25), pairs within one offset, all
/// 3DLoMatch-like, GT from the frame poses.
#[test]
fn dev3_manifest_uses_other_fragment_boundaries() {
    dev_manifest_uses_other_fragment_boundaries("redkitchen-dev3.toml", [12, 37], 14);
}

/// The fourth development set (fusion study, fourth round): fragments at 50k+6 and 50k+31.
#[test]
fn dev4_manifest_uses_other_fragment_boundaries() {
    dev_manifest_uses_other_fragment_boundaries("redkitchen-dev4.toml", [6, 31], 15);
}

/// The fifth development set (fusion study, fifth round): fragments at 50k+18 and 50k+43.
#[test]
fn dev5_manifest_uses_other_fragment_boundaries() {
    dev_manifest_uses_other_fragment_boundaries("redkitchen-dev5.toml", [18, 43], 13);
}

fn dev_manifest_uses_other_fragment_boundaries(file: &str, offsets: [usize; 2], pairs: usize) {
    use cgenreg::dataset::manifest::FragmentSource;
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dev = Dataset::load(&manifest(file)).unwrap();
    let first = |id: &str| match &dev.fragment(id).unwrap().source {
        FragmentSource::Rgbd { range, .. } => (range.first, range.count),
        _ => panic!("{id}: not an RGB-D fragment"),
    };
    assert_eq!(dev.fragments().len(), 18);
    for f in dev.fragments() {
        let (s, n) = first(&f.id);
        assert!(offsets.contains(&(s % 50)) && n == 50, "{}: {s} {n}", f.id);
    }
    assert_eq!(dev.pairs().len(), pairs);
    assert_eq!(dev.pairs_in_split("3DLoMatch-like").count(), pairs);
    for p in dev.pairs() {
        let (t, s) = (first(&p.target).0, first(&p.source).0);
        assert_eq!(t % 50, s % 50, "{}: pairs stay within one offset", p.id);
        assert!(p.gt_target_from_source.is_some(), "{}", p.id);
    }
}

/// The revisit set (docs/ablation.md, "Revisits") follows its frozen rule: fragments at
/// 50k+10/20/30/40 (no evaluated or development boundary), ten pairs at least 200 frames apart
/// (earlier = target), in order of GT rotation, no two nearly the same revisit, GT from the poses;
/// the rotations and overlaps it records are the data's.
#[test]
fn revisit_manifest_follows_its_rule() {
    use cgenreg::dataset::manifest::FragmentSource;
    use cgenreg::metrics::overlap::pair_overlap;
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let ds = Dataset::load(&manifest("redkitchen-revisit.toml")).unwrap();
    let first = |id: &str| match &ds.fragment(id).unwrap().source {
        FragmentSource::Rgbd { range, .. } => (range.first, range.count),
        _ => panic!("{id}: not an RGB-D fragment"),
    };
    for f in ds.fragments() {
        let (s, n) = first(&f.id);
        assert!(
            [10, 20, 30, 40].contains(&(s % 50)) && n == 50,
            "{}: {s} {n}",
            f.id
        );
    }
    let seq = RgbdSequence::open(&root.join("7scenes-redkitchen-rgbd")).unwrap();
    assert_eq!(ds.pairs().len(), 10);
    let mut taken: Vec<(usize, usize)> = Vec::new();
    let mut last_angle = f64::INFINITY;
    for p in ds.pairs() {
        let (t, s) = (first(&p.target).0, first(&p.source).0);
        assert!(s >= t + 200, "{}: {t} {s}", p.id);
        assert!(
            taken
                .iter()
                .all(|&(a, b)| a.abs_diff(t) >= 50 || b.abs_diff(s) >= 50),
            "{}: nearly the same revisit as an earlier pair",
            p.id
        );
        taken.push((t, s));
        let from_poses =
            seq.world_from_camera(t).unwrap().inverse() * seq.world_from_camera(s).unwrap();
        let gt = p.gt_target_from_source.unwrap();
        assert!((gt.to_homogeneous() - from_poses.to_homogeneous()).amax() < 1e-12);
        let angle = gt.rotation.angle().to_degrees();
        assert!(
            angle <= last_angle + 1e-9,
            "{}: not in rotation order",
            p.id
        );
        last_angle = angle;
        assert!(angle > 15.0, "{}: {angle}°", p.id);
    }
    // The overlap rule on the pair that passes it most narrowly.
    let pair = ds.load_pair("redkitchen-revisit/f020-f380").unwrap();
    let o = pair_overlap(
        &pair.source.cloud,
        &pair.target.cloud,
        &pair.gt_target_from_source.unwrap(),
    );
    assert!(o.max() >= 0.1 && o.max() < 0.11, "{o:?}");
}
