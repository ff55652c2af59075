//! SpinNet's Rust patch extraction and ONNX inference against the authors' torch code on real
//! patches (a redkitchen fragment, a KITTI 07 scan): the dumps and exports that
//! `scripts/spinnet_export.sh` writes under `target/spinnet` (research-only weights, never in
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
    // 4. the descriptor: Rust grouping + ONNX Runtime against the authors' torch forward
    let got = net.run_grouped(ours, b).unwrap();
    let scale = desc.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let diff = max_diff(&got, &desc);
    let worst_cos = (0..b)
        .map(|i| cosine(&got[i * 32..(i + 1) * 32], &desc[i * 32..(i + 1) * 32]))
        .fold(1.0, f64::min);
    eprintln!(
        "{}: descriptor max diff {diff:.2e} (values up to {scale:.2}), smallest cosine {worst_cos:.7}",
        p.name()
    );
    assert!(worst_cos > 0.9999, "{worst_cos}");
    assert!(diff < 1e-3 * scale.max(1.0), "{diff}");
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
