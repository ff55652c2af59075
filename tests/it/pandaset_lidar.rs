//! Guards assets/manifests/pandaset-lidar.toml: the four PandaSet frames load with the counts of
//! the data's MANIFEST, the GT direction is right (T_ego000000_from_world maps world_000000 onto
//! ego_000000 point for point), and under the GT the two clouds of each pair overlap far more
//! than under identity. Fast: loading and nearest neighbours only, no registration.

use crate::common;
use cgenreg::dataset::Dataset;
use nalgebra::Isometry3;
use std::path::Path;

fn manifest() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/pandaset-lidar.toml")
}

#[test]
fn pandaset_manifest_loads_with_the_right_ground_truth() {
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let ds = Dataset::load(&manifest()).unwrap();
    for (id, n) in [
        ("ego_000000", 105_227),
        ("world_000000", 105_227),
        ("world_000040", 107_146),
        ("world_000070", 106_928),
    ] {
        let s = ds.load_fragment(id).unwrap();
        assert_eq!(s.cloud.len(), n, "{id}");
        let it = s.cloud.intensity.as_ref().expect("LiDAR intensity");
        assert!(
            it.iter().all(|v| (0.0..=255.0).contains(v)),
            "{id}: intensity 0-255"
        );
        assert!(s.frames.is_none(), "{id}: no camera frames");
    }
    let ids: Vec<String> = ds.pairs().iter().map(|p| p.id.clone()).collect();
    assert_eq!(
        ids,
        [
            "pandaset/ego_000000-world_000040",
            "pandaset/ego_000000-world_000070"
        ]
    );

    // Direction: the same scan in both frames, same order. p_ego = T * p_world.
    let gt = ds.pairs()[0].gt_target_from_source.unwrap();
    let ego = ds.load_fragment("ego_000000").unwrap().cloud;
    let w0 = ds.load_fragment("world_000000").unwrap().cloud;
    let worst = w0
        .points
        .iter()
        .zip(&ego.points)
        .map(|(w, e)| ((gt * w.cast::<f64>()) - e.cast::<f64>()).norm())
        .fold(0.0, f64::max);
    println!("T_ego000000_from_world * world_000000 vs ego_000000: max residual {worst:.2e} m");
    assert!(worst < 1e-3, "{worst}");
    let angle = gt.rotation.angle().to_degrees();
    assert!((angle - 130.7).abs() < 0.2, "{angle}");

    // Each pair: overlap within 0.5 m under GT is high, under identity low.
    for (k, p) in ds.pairs().iter().enumerate() {
        let pair = ds.load_pair(&p.id).unwrap();
        let gt = pair.gt_target_from_source.unwrap();
        let (s, t) = (&pair.source.cloud.points, &pair.target.cloud.points);
        let with_gt = common::overlap(s, t, &gt, 0.5);
        let ident = common::overlap(s, t, &Isometry3::identity(), 0.5);
        println!(
            "{}: source points within 0.5 m of the target: GT {with_gt:.3}, identity {ident:.3}",
            p.id
        );
        let floor = if k == 0 { 0.35 } else { 0.15 };
        assert!(
            with_gt > floor && with_gt > 3.0 * ident,
            "{}: {with_gt} vs {ident}",
            p.id
        );
    }
}

/// `--lidar-origin estimated` places each scan's f-theta cameras at the sensor position found
/// from the scan's own ground rings (no pose, no GT). Checked where the sensor position is known:
/// `ego_000000` is in its sensor frame and `world_000000` is the same scan in the world frame
/// whose origin is that sensor, so both must give (0, 0). Frames 40 and 70 have no known sensor
/// position here; their estimates are printed, and must lie in the empty disk the car leaves
/// (no scan point within 1 m horizontally) and be tens of metres from the origin (the car drove).
#[test]
fn pandaset_sensor_origin_is_recovered_from_the_scan() {
    use cgenreg::camera::sensor_origin::estimate_sensor_origin;
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let ds = Dataset::load(&manifest()).unwrap();
    for (id, known) in [
        ("ego_000000", Some([0.0, 0.0])),
        ("world_000000", Some([0.0, 0.0])),
        ("world_000040", None),
        ("world_000070", None),
    ] {
        let cloud = ds.load_fragment(id).unwrap().cloud;
        let est = estimate_sensor_origin(&cloud.points).unwrap();
        let o = est.origin;
        println!(
            "{id}: sensor origin estimate ({:.3}, {:.3}, {:.3}) m (coarse {:.2?}, {} line cells, \
             {} ring points)",
            o.x, o.y, o.z, est.coarse, est.line_cells, est.ring_points
        );
        match known {
            Some(k) => {
                let err = ((o.x - k[0]).powi(2) + (o.y - k[1]).powi(2)).sqrt();
                assert!(err < 0.25, "{id}: {err} m from the known sensor position");
            }
            None => {
                assert!(o.coords.norm() > 10.0, "{id}: {o:?}");
                // the sensor's own empty disk: few points within 1 m horizontally (the near-sensor
                // returns of ego_000000 number about 300 of 105k)
                let near = cloud
                    .points
                    .iter()
                    .filter(|p| ((p.x as f64 - o.x).powi(2) + (p.y as f64 - o.y).powi(2)) < 1.0)
                    .count();
                assert!(near < 1000, "{id}: {near} points within 1 m");
            }
        }
    }
}

/// The scale search (`outdoor-search`, the manifest's preset): the registration at the voxels
/// 0.3, 0.6 and 1.2 m, the pose most consistent with both scans' range views kept. Guards the
/// headline (both PandaSet pairs at KITTI's 5° / 2 m, where the single 0.3 m voxel of the
/// published KITTI configuration registers neither) and one development pair of the choice
/// (docs/outdoor.md, "Scale hypotheses"). Every hypothesis is in the report, and the kept one
/// has the largest visibility score.
#[test]
fn pandaset_pairs_register_with_the_scale_search() {
    use cgenreg::dataset::preset::Preset;
    use cgenreg::pipeline::{RegisterParams, Registration};
    let Some(_root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let ds = Dataset::load(&manifest()).unwrap();
    assert_eq!(ds.preset, Some(Preset::OutdoorSearch));
    let dev = Dataset::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/pandaset-dev.toml"),
    )
    .unwrap();
    // the development pairs never involve frame 0, which every evaluated pair has
    assert!(dev
        .pairs()
        .iter()
        .all(|p| !p.id.contains("000000") && !ds.pairs().iter().any(|q| q.id == p.id)));
    let dir = tempfile::tempdir().unwrap();
    let cache = cgenreg::cache::Cache::open(dir.path()).unwrap();
    let runs = [
        (&ds, "pandaset/ego_000000-world_000040"),
        (&ds, "pandaset/ego_000000-world_000070"),
        (&dev, "pandaset-dev/world_000070-world_000040"),
    ];
    // geometry alone as `register` and `bench` run it without --wfm: nearest-neighbour selection
    let mut params = RegisterParams::preset(Preset::OutdoorSearch);
    params.fusion.selection = cgenreg::fusion::select::Selection::RowNn;
    for (set, id) in runs {
        let pair = set.load_pair(id).unwrap();
        let r = Registration::new(&params).cache(&cache).run(&pair).unwrap();
        let m = r.metrics.as_ref().unwrap();
        let report = r
            .scales
            .as_ref()
            .expect("a scale search reports its hypotheses");
        println!(
            "{id}: RRE {:.2}°, RTE {:.3} m, {}; {}",
            m.rre_deg,
            m.rte_m,
            if m.success { "success" } else { "failure" },
            report.provenance()
        );
        let voxels: Vec<f64> = report.hypotheses.iter().map(|h| h.voxel).collect();
        assert_eq!(voxels.len(), 3, "{voxels:?}");
        assert!((voxels[2] - 1.2).abs() < 1e-9, "{voxels:?}");
        let best = report.hypotheses.iter().map(|h| h.score).max().unwrap();
        let kept = report
            .hypotheses
            .iter()
            .find(|h| h.voxel == report.chosen_voxel)
            .unwrap();
        assert_eq!(kept.score, best);
        assert!(
            (report.theta - 0.6).abs() < 1e-9,
            "scored at the finest threshold"
        );
        assert!(m.success, "{id}: {m:?}");
    }
}
