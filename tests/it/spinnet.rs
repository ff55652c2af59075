//! SpinNet's Rust patch extraction and ONNX inference against the authors' torch code on real
//! patches (a redkitchen fragment, a KITTI 07 scan): the dumps and exports that
//! `models/spinnet_export.sh` writes under `target/spinnet` (research-only weights, never in
//! the repository). Without them the tests skip, and fail under `CI=true`, like the data.
#![cfg(feature = "onnx")]

use cgenreg::features::spinnet::model::{default_model_dir, SpinNet};
use cgenreg::features::spinnet::{ball_query, grid, invariant, patch, Protocol};
use cgenreg::io::npy::{read_npz, NpyArray};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// The export and parity dump of `p`, or None to skip (a failure under CI=true). The
/// checkpoints must be there too: without them there is nothing to export.
fn artefacts(p: Protocol) -> Option<(PathBuf, BTreeMap<String, NpyArray>)> {
    let data = cgenreg::testing::test_data_root()?;
    cgenreg::testing::require_file(&data, "../models/spinnet/3DMatch_best.pkl")?;
    let dir = default_model_dir();
    let onnx = cgenreg::testing::require_file(&dir, &p.onnx_file())?;
    let npz = cgenreg::testing::require_file(&dir, &format!("parity-{}.npz", p.name()))?;
    Some((onnx, read_npz(&npz).unwrap()))
}

fn points(a: &NpyArray, i: usize) -> Vec<[f32; 3]> {
    let v = a.to_f32();
    let n = a.shape[1];
    v[i * n * 3..(i + 1) * n * 3]
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect()
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let dot: f64 = a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum();
    let n = |v: &[f32]| v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    dot / (n(a) * n(b))
}

/// Per protocol: the local frame, the grouping from the authors' own local points (exact: the
/// same f32 ball test, the same order), the grouping from the patch (3DMatch's frame comes from
/// an f64 eigen solver instead of torch's f32 one), and the descriptor through ONNX Runtime.
fn parity(p: Protocol) {
    let Some((onnx, d)) = artefacts(p) else {
        return;
    };
    let g = p.geometry();
    let centres = grid::voxel_centres(&g);
    let (patches, local, grouped, desc) = (
        &d["patches"],
        &d["local"],
        &d["grouped"],
        d["desc_torch"].to_f32(),
    );
    let b = patches.shape[0];
    assert_eq!(grouped.shape, vec![b, g.voxels(), g.voxel_sample, 3]);
    let want_all = grouped.to_f32();
    let net = SpinNet::load(&onnx, p).unwrap();
    let mut ours = Vec::new();
    let mut worst_local = 0.0f32;
    let mut worst_samples = 0.0f64;
    // the patches whose Rust grouping equals the authors' sample for sample
    let mut exact = Vec::new();
    for i in 0..b {
        let want = &want_all[i * g.grouped_len()..(i + 1) * g.grouped_len()];
        // 1. the local frame
        let l = patch::local_points(&g, &points(patches, i));
        let theirs = points(local, i);
        worst_local = worst_local.max(max_diff(l.as_flattened(), theirs.as_flattened()));
        // 2. ball query + var_to_invar from the authors' local points: same samples, same order
        let mut from_theirs = ball_query::group(&g, &theirs, &centres);
        invariant::var_to_invar(&g, &mut from_theirs);
        let m = max_diff(&from_theirs, want);
        assert!(
            m <= 1e-6,
            "{}: grouping from the authors' local points off by {m}",
            p.name()
        );
        // 3. the whole Rust path from the patch
        let full = patch::grouped(&g, &points(patches, i), &centres);
        let off = full
            .chunks_exact(3)
            .zip(want.chunks_exact(3))
            .filter(|(a, b)| max_diff(a, b) > 1e-5)
            .count();
        worst_samples = worst_samples.max(off as f64 / (full.len() / 3) as f64);
        exact.push(off == 0);
        ours.extend(full);
    }
    eprintln!(
        "{}: local frame max diff {worst_local:.2e}, samples that differ {:.4} %",
        p.name(),
        100.0 * worst_samples
    );
    match p {
        // the frame's rotation agrees to float rounding; a few samples sitting on a ball's edge
        // may switch in or out
        Protocol::ThreeDMatch => {
            assert!(worst_local < 1e-5, "{worst_local}");
            assert!(worst_samples < 1e-3, "{worst_samples}");
        }
        Protocol::Kitti => {
            assert_eq!(worst_local, 0.0);
            assert_eq!(worst_samples, 0.0);
        }
    }
    // 4. the network: ONNX Runtime on the authors' own grouping against their torch forward
    let scale = desc.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let tol = 1e-3 * scale.max(1.0);
    let net_only = max_diff(&net.run_grouped(want_all, b).unwrap(), &desc);
    assert!(
        net_only < tol,
        "ONNX vs torch on the same grouping: {net_only}"
    );
    // 5. the descriptor of the whole Rust path (grouping + ONNX Runtime): as close where the
    // grouping was exact; where a sample on a ball's edge switched (3DMatch's frame differs
    // by float rounding between solvers and CPUs), the same direction
    let got = net.run_grouped(ours, b).unwrap();
    let row = |v: &[f32], i: usize| v[i * 32..(i + 1) * 32].to_vec();
    let diff = (0..b)
        .filter(|&i| exact[i])
        .map(|i| max_diff(&row(&got, i), &row(&desc, i)))
        .fold(0.0f32, f32::max);
    let worst_cos = (0..b)
        .map(|i| cosine(&row(&got, i), &row(&desc, i)))
        .fold(1.0, f64::min);
    eprintln!(
        "{}: ONNX vs torch {net_only:.2e}; descriptor max diff {diff:.2e} over {} of {b} patches \
         grouped exactly (values up to {scale:.2}), smallest cosine {worst_cos:.7}",
        p.name(),
        exact.iter().filter(|e| **e).count()
    );
    assert!(worst_cos > 0.9999, "{worst_cos}");
    assert!(diff < tol, "{diff}");
}

#[test]
fn rust_patches_and_onnx_match_the_authors_torch_3dmatch() {
    parity(Protocol::ThreeDMatch);
}

#[test]
fn rust_patches_and_onnx_match_the_authors_torch_kitti() {
    parity(Protocol::Kitti);
}

#[test]
fn a_missing_export_is_an_error_naming_the_file_and_the_script() {
    let e = SpinNet::load(
        std::path::Path::new("no/such/spinnet-3dmatch.onnx"),
        Protocol::ThreeDMatch,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("no/such/spinnet-3dmatch.onnx"), "{e}");
    assert!(e.contains("spinnet_export.sh"), "{e}");
}

/// The geometric branch as SpinNet through `register`: a `geo-spinnet` cache entry per scan,
/// a second run served from it with the same result, the model and keypoint count in the
/// result's provenance, and the stage key following the keypoint count and the protocol.
/// Six keypoints per scan keep it to a few seconds; registration quality is measured in
/// BENCHMARKS.md, not here.
#[test]
fn spinnet_geometry_is_a_cached_stage_with_its_provenance() {
    use cgenreg::cache::Cache;
    use cgenreg::dataset::Dataset;
    use cgenreg::pipeline::params::{GeoFeatureSource, Preset};
    use cgenreg::pipeline::stages::geo_spinnet::{self, SpinNetInput};
    use cgenreg::pipeline::{Memo, RegisterParams, Registration};
    let Some((onnx, _)) = artefacts(Protocol::Kitti) else {
        return;
    };
    let manifest =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/kitti07.toml");
    let pair = Dataset::load(&manifest)
        .unwrap()
        .load_pair("kitti07/0-1")
        .unwrap();
    let mut p = RegisterParams::preset(Preset::Outdoor);
    p.geo_features = GeoFeatureSource::Spinnet {
        protocol: Protocol::Kitti,
        model: onnx.clone(),
        keypoints: 6,
    };
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let first = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert!(
        first.geo_features.starts_with("spinnet-kitti@"),
        "{}",
        first.geo_features
    );
    assert!(first.geo_features.contains("n=6"), "{}", first.geo_features);
    assert_eq!((first.n_source_keypoints, first.n_target_keypoints), (6, 6));
    let status = |r: &cgenreg::pipeline::RegistrationResult, s: &str| {
        r.timings
            .iter()
            .find(|t| t.stage == s)
            .map(|t| t.status.clone())
            .unwrap()
    };
    assert_eq!(status(&first, "spinnet source"), "computed");
    let entries = std::fs::read_dir(dir.path().join(geo_spinnet::STAGE))
        .unwrap()
        .count();
    assert_eq!(entries, 2, "one entry per scan");
    let second = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert_eq!(status(&second, "spinnet source"), "cached");
    assert_eq!(status(&second, "spinnet target"), "cached");
    assert_eq!(second.target_from_source, first.target_from_source);
    assert_eq!(second.source_keypoints, first.source_keypoints);
    // the key follows the keypoint count, the protocol and the model file
    let memo = Memo::default();
    let input = |protocol, keypoints| SpinNetInput {
        protocol,
        model: &onnx,
        keypoints,
        voxel: 0.3,
    };
    let key = |i: &SpinNetInput| {
        let id = geo_spinnet::model_id(&memo, i).unwrap();
        geo_spinnet::key(&pair.source, i, &id).unwrap().hash
    };
    let base = key(&input(Protocol::Kitti, 6));
    assert_ne!(base, key(&input(Protocol::Kitti, 7)));
    assert_ne!(base, key(&input(Protocol::ThreeDMatch, 6)));
}

/// The CLI's `--geo-features` reaches the pipeline's own parameter type, and the settings
/// round-trip through JSON as a run file writes them.
#[test]
fn geo_features_option_sets_the_pipelines_parameters() {
    use cgenreg::cli::args::PipelineArgs;
    use cgenreg::pipeline::params::GeoFeatureSource;
    use clap::Parser;
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        p: PipelineArgs,
    }
    let cli = Cli::try_parse_from([
        "x",
        "--geo-features",
        "spinnet-kitti",
        "--spinnet-keypoints",
        "300",
        "--spinnet-model",
        "exports/k.onnx",
    ])
    .unwrap();
    let p = cli.p.to_params(false, None);
    assert_eq!(
        p.geo_features,
        GeoFeatureSource::Spinnet {
            protocol: Protocol::Kitti,
            model: "exports/k.onnx".into(),
            keypoints: 300,
        }
    );
    let json = serde_json::to_value(&p).unwrap();
    assert_eq!(json["geo_features"]["kind"], "spinnet");
    assert_eq!(json["geo_features"]["protocol"], "kitti");
    let back: cgenreg::pipeline::RegisterParams = serde_json::from_value(json).unwrap();
    assert_eq!(back, p);
    let d = Cli::try_parse_from(["x", "--geo-features", "spinnet-3dmatch"]).unwrap();
    match d.p.to_params(false, None).geo_features {
        GeoFeatureSource::Spinnet {
            protocol,
            model,
            keypoints,
        } => {
            assert_eq!(protocol, Protocol::ThreeDMatch);
            assert!(
                model.ends_with("spinnet-3dmatch.onnx"),
                "{}",
                model.display()
            );
            assert_eq!(
                keypoints,
                cgenreg::pipeline::params::SPINNET_DEFAULT_KEYPOINTS
            );
        }
        other => panic!("{other:?}"),
    }
    assert!(Cli::try_parse_from(["x", "--geo-features", "spinnet"]).is_err());
    assert!(Cli::try_parse_from(["x", "--spinnet-keypoints", "5"]).is_err());
}

/// `register` and `bench` open the stage cache for SpinNet (as for FPFH and the image branch),
/// so each scan is described once across the pairs of a run; `--no-cache` keeps it closed.
#[test]
fn spinnet_runs_open_the_stage_cache() {
    use cgenreg::cli::args::{ImageArgs, PipelineArgs};
    use clap::Parser;
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        p: PipelineArgs,
        #[command(flatten)]
        i: ImageArgs,
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let open = |args: &[&str]| {
        let c = Cli::try_parse_from(args).unwrap();
        c.i.params_and_cache(&c.p).unwrap().1.is_some()
    };
    assert!(open(&[
        "x",
        "--geo-features",
        "spinnet-kitti",
        "--cache-dir",
        d
    ]));
    assert!(!open(&[
        "x",
        "--geo-features",
        "spinnet-kitti",
        "--no-cache"
    ]));
}
