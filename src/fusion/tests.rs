//! End-to-end tests of `match_then_fuse` on planted permutations.

use super::*;

use crate::testing::Lcg as Rng;

/// Roughly normal (sum of 4 uniforms), zero mean, unit variance.
fn normal(rng: &mut Rng) -> f32 {
    ((0..4).map(|_| rng.unit_f32()).sum::<f32>() - 2.0) * 3f32.sqrt()
}

/// A similarity whose entry (i, perm[i]) is raised by `signal` above noise of scale `sigma`.
fn noisy_similarity(perm: &[usize], signal: f32, sigma: f32, rng: &mut Rng) -> DenseMatrix {
    let n = perm.len();
    DenseMatrix::from_fn(n, n, |i, j| {
        let v = sigma * normal(rng) + if perm[i] == j { signal } else { 0.0 };
        v.clamp(-1.0, 1.0)
    })
    .unwrap()
}

fn permutation(n: usize, rng: &mut Rng) -> Vec<usize> {
    let mut p: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        let j = (rng.unit_f32() * (i + 1) as f32) as usize % (i + 1);
        p.swap(i, j);
    }
    p
}

fn correct(c: &[Correspondence], perm: &[usize]) -> usize {
    c.iter()
        .filter(|c| perm[c.src as usize] == c.tgt as usize)
        .count()
}

#[test]
fn noisy_and_recovers_more_than_either_branch() {
    let n = 600;
    let mut rng = Rng(42);
    let perm = permutation(n, &mut rng);
    let s_img = noisy_similarity(&perm, 0.55, 0.2, &mut rng);
    let s_geo = noisy_similarity(&perm, 0.55, 0.2, &mut rng);
    let run = |mode, selection| {
        let p = FusionParams {
            mode,
            selection,
            ..FusionParams::default()
        };
        match_then_fuse(Some((&s_img, None, None)), Some(&s_geo), &p).unwrap()
    };
    for sel in [Selection::MutualNn, Selection::TopK(n / 2)] {
        let img = correct(&run(FusionMode::ImageOnly, sel).correspondences, &perm);
        let geo = correct(&run(FusionMode::GeometryOnly, sel).correspondences, &perm);
        let and = correct(&run(FusionMode::NoisyAnd, sel).correspondences, &perm);
        let or = correct(&run(FusionMode::NoisyOr, sel).correspondences, &perm);
        eprintln!("{sel:?}: image {img}, geometry {geo}, noisy-and {and}, noisy-or {or}");
        assert!(
            img > n / 10 && geo > n / 10,
            "branches should be informative"
        );
        assert!(
            img < n * 9 / 10 && geo < n * 9 / 10,
            "branches should be noisy"
        );
        assert!(
            and as f64 > 1.2 * img.max(geo) as f64,
            "{and} vs {img}/{geo}"
        );
    }
    // The reference configuration also beats each branch alone.
    let refp = FusionParams {
        selection: Selection::TopK(n / 2),
        ..FusionParams::reference()
    };
    let fused = match_then_fuse(Some((&s_img, None, None)), Some(&s_geo), &refp).unwrap();
    let single = FusionParams {
        mode: FusionMode::ImageOnly,
        ..refp
    };
    let img = match_then_fuse(Some((&s_img, None, None)), None, &single).unwrap();
    assert!(correct(&fused.correspondences, &perm) > correct(&img.correspondences, &perm));
}

#[test]
fn output_is_consistent_with_its_posteriors() {
    let n = 120;
    let mut rng = Rng(7);
    let perm = permutation(n, &mut rng);
    let s_img = noisy_similarity(&perm, 0.6, 0.15, &mut rng);
    let s_geo = noisy_similarity(&perm, 0.6, 0.15, &mut rng);
    let rv: Vec<bool> = (0..n).map(|i| i % 6 != 0).collect();
    let cv: Vec<bool> = (0..n).map(|j| j % 7 != 0).collect();
    let p = FusionParams::default();
    let out = match_then_fuse(Some((&s_img, Some(&rv), Some(&cv))), Some(&s_geo), &p).unwrap();
    let (pi_, pg) = (out.p_img.as_ref().unwrap(), out.p_geo.as_ref().unwrap());
    assert_eq!(
        *pi_,
        calibrate(&s_img, Some(&rv), Some(&cv), p.calibration_img).unwrap()
    );
    let direct = fuse(Some(pi_), Some(pg), FusionMode::NoisyAnd, None, false).unwrap();
    for (a, b) in out.fused.data.iter().zip(&direct.data) {
        assert!((a - b).abs() <= 1e-6 * b, "{a} vs {b}");
    }
    assert_eq!(out.peak_bytes, 3 * n * n * 4);
    assert!(!out.correspondences.is_empty());
    for c in &out.correspondences {
        // Unmapped points are vetoed by the image branch.
        assert!(rv[c.src as usize] && cv[c.tgt as usize]);
        assert_eq!(c.score, out.fused.get(c.src as usize, c.tgt as usize));
    }
    assert!(out
        .correspondences
        .windows(2)
        .all(|w| w[0].score >= w[1].score));
    // Concatenation baseline runs and finds matches too.
    let cp = FusionParams {
        mode: FusionMode::Concat,
        ..p
    };
    let cat = match_then_fuse(Some((&s_img, Some(&rv), Some(&cv))), Some(&s_geo), &cp).unwrap();
    assert!(correct(&cat.correspondences, &perm) > n / 2);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let a = DenseMatrix::zeros(4, 5).unwrap();
    let b = DenseMatrix::zeros(5, 4).unwrap();
    let p = FusionParams::default();
    assert!(match_then_fuse(Some((&a, None, None)), Some(&b), &p).is_err());
    assert!(match_then_fuse(None, None, &p).is_err());
    assert!(match_then_fuse(Some((&a, None, None)), None, &p).is_err());
    assert!(match_then_fuse(Some((&a, Some(&[true; 3]), None)), Some(&a), &p).is_err());
    let broken = DenseMatrix {
        rows: 4,
        cols: 5,
        data: vec![0.0; 7],
    };
    assert!(match_then_fuse(Some((&broken, None, None)), Some(&a), &p).is_err());
    let geo_only = FusionParams {
        mode: FusionMode::GeometryOnly,
        ..p
    };
    let g = match_then_fuse(None, Some(&a), &geo_only).unwrap();
    assert!(g.p_img.is_none());
    // A constant similarity gives uniform rows; column ties go to the lowest source index.
    assert_eq!(g.correspondences.len(), 1);
    assert_eq!((g.correspondences[0].src, g.correspondences[0].tgt), (0, 0));
}

#[test]
fn params_round_trip_through_json() {
    for p in [FusionParams::default(), FusionParams::reference()] {
        let s = serde_json::to_string(&p).unwrap();
        assert_eq!(serde_json::from_str::<FusionParams>(&s).unwrap(), p);
    }
    let partial: FusionParams = serde_json::from_str(r#"{"mode":"NoisyOr"}"#).unwrap();
    assert_eq!(partial.mode, FusionMode::NoisyOr);
    assert_eq!(partial.selection, Selection::MutualNn);
}

/// The one-pass path of the default configuration gives exactly what the general path
/// (calibrate x 2, rank keys, select, keys to posteriors) gives, with masks and ties.
#[test]
fn one_pass_default_equals_general_path() {
    let (n, m) = (157, 211);
    let mut rng = Rng(7);
    let mut s_img = DenseMatrix::from_fn(n, m, |_, _| normal(&mut rng) * 0.3).unwrap();
    let s_geo = DenseMatrix::from_fn(n, m, |_, _| normal(&mut rng) * 0.3).unwrap();
    // Exact ties within a row and within a column.
    s_img.data[5 * m + 3] = 3.0;
    s_img.data[5 * m + 9] = 3.0;
    s_img.data[8 * m + 3] = 3.0;
    let rv: Vec<bool> = (0..n).map(|i| i % 7 != 2).collect();
    let cv: Vec<bool> = (0..m).map(|j| j % 5 != 1).collect();
    for sel in [Selection::MutualNn, Selection::RowNn] {
        for (rvo, cvo) in [(None, None), (Some(&rv[..]), Some(&cv[..]))] {
            for prior in [None, Some(1e-3)] {
                let p = FusionParams {
                    selection: sel,
                    prior,
                    calibration_geo: Calibration::RowSoftmax { tau: 0.07 },
                    ..FusionParams::default()
                };
                let got = match_then_fuse(Some((&s_img, rvo, cvo)), Some(&s_geo), &p).unwrap();
                let a = calibrate(&s_img, rvo, cvo, p.calibration_img).unwrap();
                let b = calibrate(&s_geo, None, None, p.calibration_geo).unwrap();
                let mut keys = fuse::noisy_and_rank_keys(&a, &b).unwrap();
                let mut corr = select(&keys, sel);
                fuse::rank_keys_to_posteriors(&mut keys, prior).unwrap();
                for c in &mut corr {
                    c.score = keys.get(c.src as usize, c.tgt as usize);
                }
                assert_eq!(got.p_img.as_ref(), Some(&a));
                assert_eq!(got.p_geo.as_ref(), Some(&b));
                assert_eq!(got.fused, keys);
                assert_eq!(got.correspondences, corr, "{sel:?} masks {}", rvo.is_some());
                let only = match_then_fuse_select(Some((&s_img, rvo, cvo)), Some(&s_geo), &p);
                assert_eq!(only.unwrap(), corr);
                assert!(!corr.is_empty());
            }
        }
    }
}

/// The one-pass image-only path gives exactly what the general path (row softmax of the image
/// similarity, then selection) gives, with masks, ties and invalid rows, with or without the
/// geometric similarity beside it; other selections still go the general way.
#[test]
fn one_pass_image_only_equals_general_path() {
    let (n, m) = (157, 211);
    let mut rng = Rng(11);
    let mut s_img = DenseMatrix::from_fn(n, m, |_, _| normal(&mut rng) * 0.3).unwrap();
    let s_geo = DenseMatrix::from_fn(n, m, |_, _| normal(&mut rng) * 0.3).unwrap();
    s_img.data[5 * m + 3] = 3.0;
    s_img.data[5 * m + 9] = 3.0;
    s_img.data[8 * m + 3] = 3.0;
    let rv: Vec<bool> = (0..n).map(|i| i % 7 != 2).collect();
    let cv: Vec<bool> = (0..m).map(|j| j % 5 != 1).collect();
    for sel in [Selection::MutualNn, Selection::RowNn, Selection::TopK(300)] {
        for (rvo, cvo) in [(None, None), (Some(&rv[..]), Some(&cv[..]))] {
            let p = FusionParams {
                mode: FusionMode::ImageOnly,
                selection: sel,
                calibration_img: Calibration::RowSoftmax { tau: 0.07 },
                ..FusionParams::default()
            };
            let want = select(
                &calibrate(&s_img, rvo, cvo, p.calibration_img).unwrap(),
                sel,
            );
            assert!(!want.is_empty());
            for geo in [None, Some(&s_geo)] {
                let got = match_then_fuse_select(Some((&s_img, rvo, cvo)), geo, &p).unwrap();
                assert_eq!(got.len(), want.len(), "{sel:?}");
                for (a, b) in got.iter().zip(&want) {
                    assert_eq!(
                        (a.src, a.tgt, a.score.to_bits()),
                        (b.src, b.tgt, b.score.to_bits()),
                        "{sel:?} masks {}",
                        rvo.is_some()
                    );
                }
            }
        }
    }
    // the general path's errors stay: a geometric similarity of another shape
    let p = FusionParams {
        mode: FusionMode::ImageOnly,
        ..FusionParams::default()
    };
    let small = DenseMatrix::from_fn(n, m - 1, |_, _| 0.0).unwrap();
    assert!(match_then_fuse_select(Some((&s_img, None, None)), Some(&small), &p).is_err());
}

/// The feature-backed one-pass path (Noisy-AND and image only) gives exactly the correspondences (same order, same
/// scores, bit for bit) of the matrices `cosine_similarity` forms, for both selections and
/// with invalid rows and columns, also when the bands do not divide the rows.
#[test]
fn select_from_features_matches_the_matrices() {
    use crate::features::Features;
    let mut rng = Rng(7);
    let (n, m) = (517, 389);
    let mut feats = |rows: usize, dim: usize| {
        Features::new(dim, (0..rows * dim).map(|_| normal(&mut rng)).collect())
    };
    let (fs, ft) = (feats(n, 64), feats(m, 64));
    let (gs, gt) = (feats(n, 33), feats(m, 33));
    let vs: Vec<bool> = (0..n).map(|i| i % 7 != 3).collect();
    let vt: Vec<bool> = (0..m).map(|j| j % 5 != 1).collect();
    let s_img = cosine_similarity(&fs, &ft).unwrap();
    let s_geo = cosine_similarity(&gs, &gt).unwrap();
    let modes = [FusionMode::NoisyAnd, FusionMode::ImageOnly];
    for (mode, selection) in modes
        .into_iter()
        .flat_map(|m| [(m, Selection::MutualNn), (m, Selection::RowNn)])
    {
        let p = FusionParams {
            mode,
            selection,
            ..FusionParams::default()
        };
        assert!(streams_from_features(&p));
        let dense =
            match_then_fuse_select(Some((&s_img, Some(&vs), Some(&vt))), Some(&s_geo), &p).unwrap();
        let streamed = match_then_fuse_select_features((&fs, &vs, &ft, &vt), (&gs, &gt), &p)
            .unwrap()
            .unwrap();
        assert!(!dense.is_empty());
        assert_eq!(dense.len(), streamed.len(), "{mode:?} {selection:?}");
        for (a, b) in dense.iter().zip(&streamed) {
            assert_eq!(
                (a.src, a.tgt, a.score.to_bits()),
                (b.src, b.tgt, b.score.to_bits())
            );
        }
    }
    // other configurations are left to the matrices
    let p = FusionParams {
        mode: FusionMode::NoisyOr,
        ..FusionParams::default()
    };
    assert!(
        match_then_fuse_select_features((&fs, &vs, &ft, &vt), (&gs, &gt), &p)
            .unwrap()
            .is_none()
    );
    // mismatched sizes are an error
    let d = FusionParams::default();
    assert!(match_then_fuse_select_features((&fs, &vs, &ft, &vt), (&gt, &gt), &d).is_err());
}
