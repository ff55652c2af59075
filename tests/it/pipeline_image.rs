//! The full method (built-in generator + XFeat) on the bundled synthetic demo: end to end, cache
//! hits on a second run, only fusion onward recomputed after a temperature change, and a
//! corrupted cache entry reported and recomputed, never used.
#![cfg(feature = "onnx")]

use crate::common;

use cgenreg::cache::Cache;
use cgenreg::dataset::Dataset;
use cgenreg::fusion::Calibration;
use cgenreg::pipeline::plan::{invalidated, plan, Plan, StageName};
use cgenreg::pipeline::{ImageBranchParams, RegisterParams, Registration, WfmSpec};
use std::path::Path;

/// Stages read from the cache on a repeat run (everything before the similarities).
const CACHED: &[&str] = &[
    "fpfh source",
    "fpfh target",
    // (no depth video: the built-in generator draws each view from its own depth frame)
    "generation",
    "vfm source views",
    "vfm target views",
    "lift source",
    "lift target",
    "image point features",
];

fn params() -> RegisterParams {
    common::demo_params(WfmSpec::Builtin)
}

fn status(r: &cgenreg::pipeline::RegistrationResult, stage: &str) -> String {
    r.timings
        .iter()
        .find(|t| t.stage == stage)
        .unwrap_or_else(|| panic!("no stage {stage} in {:?}", r.timings))
        .status
        .clone()
}

/// Every cached stage's keys in `keys` name entries of the cache at `dir`.
fn assert_stored(keys: &Plan, dir: &Path) {
    for s in keys.stages() {
        if matches!(s, StageName::ViewSelect | StageName::Fusion) {
            continue; // in memory
        }
        let hashes = keys.get(s).unwrap_or_else(|| panic!("{s:?} not known"));
        for h in hashes {
            let d = dir.join(s.key_name()).join(h);
            assert!(d.is_dir(), "{s:?}: no entry {}", d.display());
        }
    }
}

#[test]
fn full_method_on_demo_with_cache() {
    let manifest = common::demo_manifest();
    let ds = Dataset::load(&manifest).unwrap();
    let id = ds.pairs()[0].id.clone();
    let pair = ds.load_pair(&id).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let p = common::demo_params_5cm(WfmSpec::Builtin);

    // 1. End to end, everything computed.
    let r1 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    for s in CACHED {
        assert_eq!(status(&r1, s), "computed", "{s}");
    }
    let img = r1.image.as_ref().expect("image branch output");
    assert_eq!(img.source_views.len(), 2);
    assert_eq!(
        img.source_views
            .iter()
            .map(|v| v.generated_index)
            .collect::<Vec<_>>(),
        vec![0, 3]
    );
    assert_eq!(
        img.target_views
            .iter()
            .map(|v| v.depth_index)
            .collect::<Vec<_>>(),
        vec![1, 4]
    );
    assert!(img.source_views[0]
        .label
        .starts_with("builtin-depthshade-v1 | "));
    assert!(img.source_views[0].label.contains("| cache "));
    assert!(img.vfm.starts_with("xfeat@"));
    let linked = img.source_links.iter().filter(|l| l.is_some()).count();
    assert!(
        linked * 2 > img.source_links.len(),
        "most source keypoints should have a pixel: {linked}/{}",
        img.source_links.len()
    );
    assert!(r1.image_branch.is_some());
    assert!(r1.n_correspondences > 0);
    let m = r1.metrics.as_ref().unwrap();
    eprintln!(
        "demo: RRE {:.2} deg RTE {:.3} m, {} correspondences; timings {:?}",
        m.rre_deg, m.rte_m, r1.n_correspondences, r1.timings
    );
    // the headline accuracy: the full method within 1° / 5 cm of the demo's exact GT
    assert!(m.rre_deg < 1.0 && m.rte_m < 0.05, "demo: {m:?}");

    // The stage keys planned without running anything are the ones the run stored under and
    // filled in the plan its result carries.
    let keys = plan(&pair, &p, Some(&cache), &Default::default()).unwrap();
    assert_stored(&keys, dir.path());
    assert_eq!(r1.plan.as_ref(), Some(&keys));

    // 2. Same parameters: every stage up to the similarities is a cache hit, same pose.
    let r2 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    for s in CACHED {
        assert_eq!(status(&r2, s), "cached", "{s}");
    }
    assert_eq!(r1.target_from_source, r2.target_from_source);
    assert_eq!(r1.correspondences, r2.correspondences);

    // 3. A changed temperature: only similarity / fusion / estimate run again.
    let mut p3 = p.clone();
    p3.fusion.calibration_img = Calibration::RowSoftmax { tau: 0.05 };
    assert_eq!(
        invalidated(&pair, &p, &p3, Some(&cache), &Default::default()).unwrap(),
        [StageName::Fusion]
    );
    let r3 = Registration::new(&p3).cache(&cache).run(&pair).unwrap();
    for s in CACHED {
        assert_eq!(status(&r3, s), "cached", "{s}");
    }
    // The demo's 16k x 13.5k keypoints are above `tail::STREAM_ENTRIES`: similarity and fusion
    // then run as one streamed stage.
    let streamed = r3.timings.iter().any(|t| t.stage == "similarity+fusion");
    let tail: &[&str] = if streamed {
        &["similarity+fusion", "estimate"]
    } else {
        &["similarity", "fusion", "estimate"]
    };
    for s in tail {
        assert_eq!(status(&r3, s), "computed", "{s}");
    }

    // 4. Corrupt one VFM descriptor entry: it is reported, recomputed, and the result is as
    // before (the corrupt bytes are never used).
    let vfm_dir = dir.path().join("vfm-view");
    let entry = std::fs::read_dir(&vfm_dir)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let desc = entry.join("desc.npy");
    let mut bytes = std::fs::read(&desc).unwrap();
    let n = bytes.len();
    for b in &mut bytes[n - 64..] {
        *b ^= 0x5a;
    }
    std::fs::write(&desc, bytes).unwrap();
    let r4 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert!(
        r4.warnings
            .iter()
            .any(|w| w.contains("corrupt") && w.contains("vfm-view")),
        "{:?}",
        r4.warnings
    );
    let side_statuses = [
        status(&r4, "vfm source views"),
        status(&r4, "vfm target views"),
    ];
    assert!(
        side_statuses.iter().any(|s| s == "computed"),
        "{side_statuses:?}"
    );
    assert_eq!(r4.target_from_source, r1.target_from_source);
    // The entry was rewritten and verifies again.
    assert!(cache.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
}

#[test]
fn invalid_k_is_a_clear_error() {
    let manifest = common::demo_manifest();
    let ds = Dataset::load(&manifest).unwrap();
    let pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    let mut p = params();
    p.image.as_mut().unwrap().k = 9;
    let e = Registration::new(&p).run(&pair).unwrap_err().to_string();
    assert!(e.contains("K = 9"), "{e}");
    // L larger than the fragment's frames.
    let mut p = params();
    p.image.as_mut().unwrap().frames_per_fragment = 50;
    let e = Registration::new(&p).run(&pair).unwrap_err().to_string();
    assert!(e.contains("L = 50"), "{e}");
}

/// The pair-conditioned path (reference §6.3, §8.1) end to end with the tiny model of MASt3R's
/// ONNX signature: K x K forward passes, a cached point-descriptor stage, and the same pose
/// again from the cache. (The tiny model is not MASt3R; only the plumbing is under test.)
#[test]
fn pair_conditioned_vfm_end_to_end() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ds = Dataset::load(&root.join("assets/demo/demo.toml")).unwrap();
    let pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let mut p = params();
    p.image.as_mut().unwrap().vfm = cgenreg::pipeline::VfmSpec::Mast3r {
        model: root.join("tests/fixtures/tiny_mast3r.onnx"),
    };
    let r1 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    let stage = "vfm view pairs + point features";
    assert_eq!(status(&r1, stage), "computed");
    assert!(r1.timings.iter().all(|t| t.stage != "vfm source views"));
    let img = r1.image.as_ref().unwrap();
    assert!(img.vfm.starts_with("mast3r@"), "{}", img.vfm);
    assert!(img.vfm.contains("2x2 view pairs"), "{}", img.vfm);
    assert!(r1.n_correspondences > 0);
    let keys = plan(&pair, &p, Some(&cache), &Default::default()).unwrap();
    assert_eq!(r1.plan.as_ref(), Some(&keys));
    assert!(keys.is_known(StageName::PairVfm) && !keys.is_known(StageName::Vfm));
    assert_stored(&keys, dir.path());
    let r2 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert_eq!(status(&r2, stage), "cached");
    assert_eq!(r1.correspondences, r2.correspondences);
    assert_eq!(r1.target_from_source, r2.target_from_source);
    // A per-image model file given as a pair model is a clear error, not a panic.
    p.image.as_mut().unwrap().vfm = cgenreg::pipeline::VfmSpec::Mast3r {
        model: root.join("models/xfeat.onnx"),
    };
    let e = Registration::new(&p).run(&pair).unwrap_err().to_string();
    assert!(e.contains("xfeat.onnx"), "{e}");
}

/// Re-fusing from kept similarity matrices (the inspector's fast path) gives exactly what the
/// full in-memory tail gives, for the image branch and for geometry alone.
#[test]
fn fuse_from_kept_similarities_equals_full_tail() {
    use cgenreg::fusion::{FusionMode, Selection};
    use cgenreg::pipeline::tail::{similarities, FusionInputs};
    let manifest = common::demo_manifest();
    let ds = Dataset::load(&manifest).unwrap();
    let pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    // What is compared (the kept similarities give the full tail's result) does not depend on
    // the keypoint count: a 10 cm grid keeps each of the twelve tails below a quarter of the
    // 5 cm grid's similarity and fusion work.
    let p = RegisterParams {
        voxel: 0.1,
        ..params()
    };
    let inputs = Registration::new(&p)
        .keep(true)
        .run(&pair)
        .unwrap()
        .inputs
        .unwrap();
    let inputs = FusionInputs::clone(&inputs);
    let geo_only = FusionInputs {
        image: None,
        image_label: None,
        ..inputs.clone()
    };
    for inp in [&inputs, &geo_only] {
        let sims = similarities(inp).unwrap();
        for (tau, mode, sel) in [
            (0.1, FusionMode::NoisyAnd, Selection::MutualNn),
            (0.05, FusionMode::NoisyOr, Selection::RowNn),
            (0.2, FusionMode::NoisyAnd, Selection::RowNn),
        ] {
            let mut q = p.clone();
            q.fusion.calibration_img = Calibration::RowSoftmax { tau };
            q.fusion.calibration_geo = Calibration::RowSoftmax { tau };
            q.fusion.mode = mode;
            q.fusion.selection = sel;
            let tail = Registration::new(&q);
            let a = tail.refuse_from_memory(&pair, inp, None).unwrap();
            let b = tail.refuse_from_memory(&pair, inp, Some(&sims)).unwrap();
            let pairs = |r: &cgenreg::pipeline::RegistrationResult| {
                let mut v = r
                    .correspondences
                    .iter()
                    .map(|c| (c.src, c.tgt))
                    .collect::<Vec<_>>();
                v.sort_unstable();
                v
            };
            assert_eq!(pairs(&a), pairs(&b), "tau {tau} {mode:?} {sel:?}");
            eprintln!(
                "tau {tau} {mode:?} {sel:?}: RRE a/b {:?} {:?}",
                a.metrics.as_ref().map(|m| m.rre_deg),
                b.metrics.as_ref().map(|m| m.rre_deg)
            );
            let d = common::pose_max_diff(&a.target_from_source, &b.target_from_source);
            assert!(d < 1e-6, "poses differ by {d}");
        }
    }
}

/// A pair given only as point clouds: the image branch renders depth frames from a virtual
/// pinhole trajectory (cached), then runs as usual, and says so.
#[test]
fn cloud_only_pair_renders_virtual_depth_frames() {
    let manifest = common::demo_manifest();
    let ds = Dataset::load(&manifest).unwrap();
    let mut pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    pair.source.frames = None;
    pair.target.frames = None;
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let p = params();
    let r = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert!(
        r.warnings.iter().any(|w| w.contains("virtual pinhole")),
        "{:?}",
        r.warnings
    );
    let img = r.image.as_ref().unwrap();
    assert_eq!(img.source_views.len(), 2);
    let linked = img.source_links.iter().filter(|l| l.is_some()).count();
    // rendered depth back-projects onto the cloud: most keypoints get a pixel
    assert!(
        linked * 2 > img.source_links.len(),
        "{linked}/{}",
        img.source_links.len()
    );
    let frames: Vec<_> = std::fs::read_dir(dir.path().join("virtual-frames"))
        .unwrap()
        .collect();
    assert_eq!(frames.len(), 2, "one folder per scan");
    // Second run: same frames from the cache, same pose, and every cached stage a hit (the
    // poses read back from the virtual-frames entry are bit for bit those computed, so the
    // lift and image-point keys repeat: no duplicate entries).
    let r2 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert_eq!(r.target_from_source, r2.target_from_source);
    for s in [
        "lift source",
        "lift target",
        "image point features",
        "generation",
    ] {
        let t = r2.timings.iter().find(|t| t.stage == s).unwrap();
        assert_eq!(t.status, "cached", "{s}: {:?}", r2.timings);
    }
    let entries = cache.list().unwrap();
    let count = |stage: &str| entries.iter().filter(|e| e.stage == stage).count();
    assert_eq!(count("lift"), 2);
    assert_eq!(count("image-points"), 1);
    assert_eq!(count("virtual-frames"), 2);
    // The virtual frames are verified entries like the others: a clean cache verifies clean.
    assert!(cache.verify_all().unwrap().iter().all(|r| r.result.is_ok()));

    // A truncated virtual-frame PNG is detected, reported and rebuilt, never used.
    let vf = entries
        .iter()
        .find(|e| e.stage == "virtual-frames")
        .unwrap();
    let png = vf.dir.join("frame-000000.depth.png");
    let bytes = std::fs::read(&png).unwrap();
    std::fs::write(&png, &bytes[..bytes.len() / 2]).unwrap();
    let r3 = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert!(
        r3.warnings
            .iter()
            .any(|w| w.contains("virtual-frames/") && w.contains("rebuilt")),
        "{:?}",
        r3.warnings
    );
    assert_eq!(r.target_from_source, r3.target_from_source);
    assert_eq!(std::fs::read(&png).unwrap(), bytes);
    assert!(cache.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
}

/// The real LiDAR pair (small_gicp, 70k points with intensity, no images): the image branch
/// renders one range image per scan from the virtual f-theta camera (appendix B.3), the
/// built-in generator shades it at 1280x640, XFeat describes it, lifting follows the rays, and
/// the fused registration agrees with the pair's reference transform.
#[test]
fn lidar_pair_goes_through_the_ftheta_camera() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let d = root.join("small-gicp-lidar-pair");
    let pair = cgenreg::dataset::pair_from_files(
        &d.join("source.ply"),
        &d.join("target.ply"),
        Some(&d.join("T_target_source.txt")),
    )
    .unwrap();
    assert!(
        pair.source.cloud.intensity.is_some(),
        "LiDAR PLY carries intensity"
    );
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let p = RegisterParams {
        voxel: 0.25,
        image: Some(ImageBranchParams {
            backend: WfmSpec::Builtin,
            frames_per_fragment: 2,
            margin: 0,
            k: 1,
            ..Default::default()
        }),
        ..Default::default()
    };
    let r = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert!(
        r.warnings.iter().any(|w| w.contains("virtual f-theta")),
        "{:?}",
        r.warnings
    );
    let img = r.image.as_ref().unwrap();
    assert!(
        img.provenance.backend.contains("1280x640"),
        "{}",
        img.provenance.backend
    );
    assert_eq!(img.source_views[0].camera.name(), "f-theta");
    assert_eq!(img.source_views[0].image.dimensions(), (1280, 640));
    // The forward camera sees about half of a 360-degree scan.
    for links in [&img.source_links, &img.target_links] {
        let linked = links.iter().filter(|l| l.is_some()).count();
        assert!(
            linked * 10 > links.len() * 3 && linked * 10 < links.len() * 8,
            "{linked}/{}",
            links.len()
        );
    }
    let m = r.metrics.as_ref().unwrap();
    assert!(m.rre_deg < 2.0 && m.rte_m < 0.15, "{m:?}");
    // One range image per scan, shared by the static camera's frames.
    let pngs: Vec<_> = walk(&dir.path().join("virtual-frames"))
        .into_iter()
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    assert_eq!(pngs.len(), 2, "{pngs:?}");

    // Two cameras back to back (appendix B.3's 360° extension), one view each: nearly every
    // keypoint of the 360° scans gets a pixel.
    let mut p2 = p.clone();
    if let Some(ib) = p2.image.as_mut() {
        ib.lidar_cameras = 2;
        ib.k = 2;
    }
    let r2 = Registration::new(&p2).cache(&cache).run(&pair).unwrap();
    assert!(r2.warnings.iter().any(|w| w.contains("2 such cameras")));
    assert!(
        !r2.warnings
            .iter()
            .any(|w| w.contains("of the 2 f-theta cameras")),
        "both cameras are looked at: {:?}",
        r2.warnings
    );
    let img2 = r2.image.as_ref().unwrap();
    let poses: Vec<_> = img2
        .source_views
        .iter()
        .map(|v| v.scan_from_camera.unwrap())
        .collect();
    let forward = |t: &nalgebra::Isometry3<f64>| t.rotation * nalgebra::Vector3::z();
    assert!(
        forward(&poses[0]).dot(&forward(&poses[1])) < -0.99,
        "opposite yaws"
    );
    for links in [&img2.source_links, &img2.target_links] {
        let linked = links.iter().filter(|l| l.is_some()).count();
        assert!(linked * 100 > links.len() * 85, "{linked}/{}", links.len());
    }
    assert!(r2.metrics.as_ref().unwrap().success);
}

fn walk(d: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(d).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// `--no-cache` on a cloud-only pair: the virtual frames go to a fresh scratch folder that
/// is removed afterwards (it used to be a fixed `cgenreg-virtual-frames` folder under the
/// system temp dir, shared by every run and never cleaned).
#[test]
fn cloud_only_pair_without_cache_leaves_no_virtual_frames() {
    let manifest = common::demo_manifest();
    let ds = Dataset::load(&manifest).unwrap();
    let mut pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    pair.source.frames = None;
    pair.target.frames = None;
    let mine = format!("cgenreg-virtual-frames-{}-", std::process::id());
    let leftovers = || -> Vec<String> {
        std::fs::read_dir(std::env::temp_dir())
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter(|n| n.starts_with(&mine))
            .collect()
    };
    let r = Registration::new(&params()).run(&pair).unwrap();
    assert!(r.warnings.iter().any(|w| w.contains("virtual pinhole")));
    assert_eq!(leftovers(), Vec::<String>::new());
}

/// The caller owns what is kept between registrations: one memo loads the VFM once for two
/// runs and remembers the input files' hashes; a memo bounded to a single file hash and model
/// gives the same result (the bound changes only what is recomputed).
#[test]
fn a_callers_memo_loads_the_model_once_and_its_bound_changes_no_result() {
    use cgenreg::pipeline::memo::Memo;
    let ds = Dataset::load(&common::demo_manifest()).unwrap();
    let pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    let p = params();
    let memo = Memo::default();
    assert_eq!(memo.sizes().models, 0);
    let a = Registration::new(&p).memo(&memo).run(&pair).unwrap();
    let after_one = memo.sizes();
    assert_eq!(after_one.models, 1, "{after_one:?}");
    let k = p.image.as_ref().unwrap().k;
    // the model file and the 2K selected views' depth frames (the built-in generator draws only
    // those: no depth video of all 2L frames)
    assert_eq!(after_one.file_hashes, 1 + 2 * k, "{after_one:?}");
    let b = Registration::new(&p).memo(&memo).run(&pair).unwrap();
    assert_eq!(memo.sizes(), after_one, "a second run adds nothing");
    let tiny = Memo::with_capacity(1, 1, 1);
    let c = Registration::new(&p).memo(&tiny).run(&pair).unwrap();
    assert_eq!(tiny.sizes().file_hashes, 1);
    for r in [&b, &c] {
        assert_eq!(r.estimate, a.estimate);
        assert_eq!(r.correspondences.len(), a.correspondences.len());
    }
}

/// A run without a cache keeps its virtual frames only in a scratch folder that is gone after the
/// run; the inputs it keeps must still let a re-fusion to `visibility` compare the poses in those
/// views (read during the run).
#[test]
fn a_refusion_to_visibility_after_an_uncached_clouds_only_run_compares_in_its_views() {
    use cgenreg::fusion::FusionMode;
    use cgenreg::pipeline::visibility::Candidate;
    let ds = Dataset::load(&common::demo_manifest()).unwrap();
    let mut pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    pair.source.frames = None;
    pair.target.frames = None;
    let mut p = params();
    p.fusion.mode = FusionMode::NoisyAnd;
    let mut r = Registration::new(&p).keep(true).run(&pair).unwrap();
    let inputs = r.inputs.take().unwrap();
    p.fusion.mode = FusionMode::Visibility;
    let v = Registration::new(&p)
        .refuse_from_memory(&pair, &inputs, None)
        .unwrap();
    let rep = v.visibility.as_ref().unwrap();
    assert_eq!(rep.views, cgenreg::dataset::ViewOrigin::Virtual);
    let poses: Vec<Candidate> = rep.candidates.iter().map(|c| c.pose).collect();
    assert_eq!(poses, Candidate::ALL);
    assert!(
        rep.candidates.iter().all(|c| c.consistent > 0),
        "{:?}",
        rep.candidates
    );
}
