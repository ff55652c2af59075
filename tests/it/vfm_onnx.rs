//! ONNX paths of the VFM module: the MASt3R pair path on a tiny model with MASt3R's signature
//! (tests/fixtures/tiny_mast3r.onnx, made by tests/fixtures/make_tiny_mast3r.py), model-file
//! errors, and the bundled XFeat model (synthetic and real 7-Scenes frames).
#![cfg(feature = "onnx")]

use cgenreg::vfm::mast3r::{self, Mast3r};
use cgenreg::vfm::xfeat::XFeat;
use cgenreg::vfm::{describe_all_pairs, PairModel, PerImageModel};
use image::{Rgb, RgbImage};
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn frame(seed: u32, w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let v = |k: u32| {
            (((x * (3 + k + seed) + y * (5 + 2 * k) + seed * 17) % 251) as f32 * 0.6
                + 60.0 * ((x as f32 * 0.02 + k as f32 + seed as f32).sin() + 1.0)) as u8
        };
        Rgb([v(0), v(1), v(2)])
    })
}

/// The tiny model's formula (see make_tiny_mast3r.py), at one pixel of the padded inputs.
fn tiny_desc(first: bool, x1: [f32; 3], x2: [f32; 3]) -> Vec<f32> {
    let w = |k: f32, o: usize, c: usize| (k * (o * 3 + c + 1) as f32).sin();
    let (ks, kc) = if first { (1.0, 2.0) } else { (3.0, 4.0) };
    let mut d: Vec<f32> = (0..24)
        .map(|o| {
            let b = if first {
                0.5 + 0.01 * o as f32
            } else {
                0.5 + 0.01 * (23 - o) as f32
            };
            b + (0..3)
                .map(|c| w(ks, o, c) * x1[c] + w(kc, o, c) * x2[c])
                .sum::<f32>()
        })
        .collect();
    let n = d.iter().map(|v| v * v).sum::<f32>().sqrt();
    d.iter_mut().for_each(|v| *v /= n);
    d
}

fn px(p: &mast3r::Prepared, x: usize, y: usize) -> [f32; 3] {
    let plane = mast3r::IN_H * mast3r::IN_W;
    let i = y * mast3r::IN_W + x;
    [p.tensor[i], p.tensor[plane + i], p.tensor[2 * plane + i]]
}

#[test]
fn mast3r_preprocessing_matches_the_reference_collate() {
    let img = frame(1, 960, 704);
    let p = mast3r::prepare(&img).unwrap();
    assert_eq!(p.resized, (512, 375));
    assert_eq!(p.tensor.len(), 3 * 384 * 512);
    // 9 zero rows at the bottom, values in [-1, 1] elsewhere
    for y in 375..384 {
        for x in [0, 200, 511] {
            assert_eq!(px(&p, x, y), [0.0; 3]);
        }
    }
    assert!(p.tensor.iter().all(|v| (-1.0..=1.0).contains(v)));
    // a constant image stays constant through LANCZOS and maps through (v/255 - 0.5)/0.5
    let flat = RgbImage::from_pixel(960, 704, Rgb([255, 0, 51]));
    let q = mast3r::prepare(&flat).unwrap();
    let v = px(&q, 100, 100);
    assert!((v[0] - 1.0).abs() < 1e-6 && (v[1] + 1.0).abs() < 1e-6 && (v[2] + 0.6).abs() < 1e-6);
    assert!(
        mast3r::prepare(&frame(0, 480, 640)).is_err(),
        "portrait frames do not fit 384x512"
    );
}

#[test]
fn mast3r_pairs_on_a_tiny_model_of_the_same_signature() {
    let model = Mast3r::load(&fixture("tiny_mast3r.onnx")).unwrap();
    eprintln!("backend: {}", cgenreg::vfm::backend_name());
    assert!(model.id().starts_with("mast3r@"));
    let src = [frame(1, 960, 704), frame(2, 960, 704)];
    let tgt = [frame(3, 960, 704), frame(4, 960, 704)];
    let out = describe_all_pairs(&model, &src, &tgt).unwrap();
    assert_eq!(out.len(), 4);
    let ps: Vec<_> = src.iter().map(|i| mast3r::prepare(i).unwrap()).collect();
    let pt: Vec<_> = tgt.iter().map(|i| mast3r::prepare(i).unwrap()).collect();
    for s in 0..2 {
        for t in 0..2 {
            let (d1, d2) = &out[s * 2 + t];
            for d in [d1, d2] {
                assert_eq!((d.width, d.height, d.dim), (512, 375, 24));
                assert!((d.stride_x - 960.0 / 512.0).abs() < 1e-6);
                assert!((d.stride_y - 704.0 / 375.0).abs() < 1e-6);
            }
            // grid cells against the formula, including the last unpadded row
            for &(x, y) in &[
                (0usize, 0usize),
                (17, 200),
                (511, 374),
                (300, 374),
                (256, 3),
            ] {
                let want1 = tiny_desc(true, px(&ps[s], x, y), px(&pt[t], x, y));
                let want2 = tiny_desc(false, px(&pt[t], x, y), px(&ps[s], x, y));
                for (g, w) in d1.cell(x as u32, y as u32).iter().zip(&want1) {
                    assert!(
                        (g - w).abs() < 1e-4,
                        "pair {s},{t} desc_1 at {x},{y}: {g} vs {w}"
                    );
                }
                for (g, w) in d2.cell(x as u32, y as u32).iter().zip(&want2) {
                    assert!(
                        (g - w).abs() < 1e-4,
                        "pair {s},{t} desc_2 at {x},{y}: {g} vs {w}"
                    );
                }
            }
            // the bottom image row samples the last real row, never the zero padding
            let bottom = d1.sample(500.0, 703.0);
            let last = d1.cell(266, 374);
            for (a, b) in bottom.iter().zip(last) {
                assert!((a - b).abs() < 0.2);
            }
        }
    }
    // pair-conditioning: desc_1 of (s0, t0) differs from desc_1 of (s0, t1)
    let a = out[0].0.cell(100, 100);
    let b = out[1].0.cell(100, 100);
    assert!(a.iter().zip(b).any(|(x, y)| (x - y).abs() > 1e-3));
    // describe_pair agrees with the batched path
    let (e1, e2) = model.describe_pair(&src[1], &tgt[0]).unwrap();
    assert_eq!(e1, out[2].0);
    assert_eq!(e2, out[2].1);
}

#[test]
fn missing_and_malformed_models_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.onnx");
    let e = Mast3r::load(&missing).unwrap_err().to_string();
    assert!(e.contains("nope.onnx"), "{e}");
    let bad = dir.path().join("garbage.onnx");
    std::fs::write(&bad, vec![0xA5u8; 4096]).unwrap();
    let e = XFeat::load(&bad).unwrap_err().to_string();
    assert!(e.contains("garbage.onnx") && e.contains("XFeat"), "{e}");
    let empty = dir.path().join("empty.onnx");
    std::fs::write(&empty, b"").unwrap();
    let e = XFeat::load(&empty).unwrap_err().to_string();
    assert!(e.contains("empty.onnx") && e.contains("0-byte"), "{e}");
    // a valid ONNX file with the wrong signature
    let e = XFeat::load(&fixture("tiny_mast3r.onnx"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("image") && e.contains("img1"), "{e}");
}

#[test]
fn xfeat_dense_descriptors_on_a_synthetic_frame() {
    let model = XFeat::load_default().unwrap();
    let d = model.describe(&frame(5, 960, 704)).unwrap();
    assert_eq!((d.width, d.height, d.dim), (120, 88, 64));
    assert_eq!((d.stride_x, d.stride_y), (8.0, 8.0));
    for y in (0..88).step_by(13) {
        for x in (0..120).step_by(11) {
            let n: f32 = d.cell(x, y).iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-4);
        }
    }
    // a size that is not a multiple of 32 is resized; strides map back to the original
    let d = model.describe(&frame(5, 650, 490)).unwrap();
    assert_eq!((d.width, d.height), (80, 60));
    assert!((d.stride_x - 8.0 * 650.0 / 640.0).abs() < 1e-5);
    assert!(model.describe(&frame(5, 20, 500)).is_err());
}

/// The probe from STACK.md: redkitchen colour frames 0 and 50, dense mutual nearest neighbours
/// over the 1/8 grid, checked against depth + poses (the depth and colour cameras are not
/// registered pixel to pixel, hence a 12 px tolerance). STACK.md measured ~2,500 matches, 81 %.
#[test]
fn xfeat_matches_agree_with_depth_and_poses_on_real_frames() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dir = root.join("7scenes-redkitchen-rgbd");
    let seq = cgenreg::dataset::rgbd_sequence::RgbdSequence::open(&dir).unwrap();
    let k = seq.intrinsics().unwrap();
    let model = XFeat::load_default().unwrap();
    let load = |i: usize| {
        image::open(seq.frame(i).unwrap().color.as_ref().unwrap())
            .unwrap()
            .to_rgb8()
    };
    let (da, db) = (
        model.describe(&load(0)).unwrap(),
        model.describe(&load(50)).unwrap(),
    );
    let depth = cgenreg::io::depth_png::read_depth_png(&seq.frame(0).unwrap().depth).unwrap();
    let b_from_a = seq.world_from_camera(50).unwrap().inverse() * seq.world_from_camera(0).unwrap();
    let n = (da.width * da.height) as usize;
    let best =
        |from: &cgenreg::vfm::DenseDescriptors, to: &cgenreg::vfm::DenseDescriptors, i: usize| {
            let q = &from.data[i * 64..(i + 1) * 64];
            (0..n)
                .map(|j| {
                    (
                        j,
                        to.data[j * 64..(j + 1) * 64]
                            .iter()
                            .zip(q)
                            .map(|(a, b)| a * b)
                            .sum::<f32>(),
                    )
                })
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap()
                .0
        };
    use rayon::prelude::*;
    let ab: Vec<usize> = (0..n).into_par_iter().map(|i| best(&da, &db, i)).collect();
    let ba: Vec<usize> = (0..n).into_par_iter().map(|j| best(&db, &da, j)).collect();
    let (mut matches, mut good) = (0, 0);
    let w = da.width as usize;
    for (i, &j) in ab.iter().enumerate().take(n) {
        if ba[j] != i {
            continue;
        }
        let (u, v) = ((i % w) as f64 * 8.0 + 3.5, (i / w) as f64 * 8.0 + 3.5);
        let Some(z) = depth.meters(u.round() as u32, v.round() as u32) else {
            continue;
        };
        let p = b_from_a * k.backproject(u, v, z as f64);
        let Some((pu, pv)) = k.project(&p) else {
            continue;
        };
        matches += 1;
        let (mu, mv) = ((j % w) as f64 * 8.0 + 3.5, (j / w) as f64 * 8.0 + 3.5);
        if ((pu - mu).powi(2) + (pv - mv).powi(2)).sqrt() <= 12.0 {
            good += 1;
        }
    }
    let ratio = good as f64 / matches as f64;
    eprintln!(
        "xfeat probe ({}): {matches} mutual matches with depth, {:.1} % within 12 px",
        cgenreg::vfm::backend_name(),
        100.0 * ratio
    );
    assert!(matches > 1500, "{matches} matches");
    assert!(ratio > 0.7, "{:.3}", ratio);
}
