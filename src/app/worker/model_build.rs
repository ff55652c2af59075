//! The inspector's model from a registration result: display clouds, matches with their GT
//! flags, views with their depth frames and visibility, the pair browser's row, PR curves, and
//! the branch posteriors of one source point (from the library's `fusion::posterior_row`).

use std::sync::Arc;

use nalgebra::{Isometry3, Point3};

use crate::app::model::StageRole;
use crate::app::model::{
    Branch, InspectorModel, MatchInfo, PairEntry, PairStatus, PlotData, Posterior, PrCurve,
    RgbImage, StageInfo, StageState, ViewCamera, ViewImage, ViewLabel,
};
use crate::dataset::ScanPair;
use crate::fusion::fuse::FusionMode;
use crate::pipeline::memo::Lru;
use crate::pipeline::tail::{FusionInputs, Similarities};
use crate::pipeline::{ImageBranchOutput, RegistrationResult};

/// A match is correct within this distance under the ground truth in the paper's figure 7.
pub const FIGURE7_CORRECT_M: f64 = 0.05;
/// Display points per cloud on top of the keypoints.
pub const DISPLAY_POINTS: usize = 150_000;
/// Candidates kept per posterior.
const POSTERIOR_CANDIDATES: usize = 400;

/// Why the image branch is not shown when no WFM is chosen.
pub const IMAGE_BRANCH_OFF: &str = "image branch off (WFM: none) — the geometric branch ran \
alone, so there are no views to show and the fused posterior equals the geometric one; choose \
a WFM under “Image branch” (oracle needs a pair with RGB-D frames)";

fn p3(p: &Point3<f32>) -> [f32; 3] {
    [p.x, p.y, p.z]
}

/// Keypoints then a strided subsample of the full cloud, at most `DISPLAY_POINTS` extra.
fn display_cloud(keypoints: &[Point3<f32>], full: &[Point3<f32>], cap: usize) -> Vec<[f32; 3]> {
    let stride = full.len().div_ceil(cap.max(1)).max(1);
    let mut out = Vec::with_capacity(keypoints.len() + full.len() / stride + 1);
    out.extend(keypoints.iter().map(p3));
    out.extend(full.iter().step_by(stride).map(p3));
    out
}

/// Precision-recall of the matches over the score threshold, points (recall, precision).
pub fn pr_curve(name: &str, matches: &[MatchInfo]) -> Option<PrCurve> {
    let mut scored: Vec<(f32, bool)> = matches
        .iter()
        .filter_map(|m| m.inlier_gt.map(|i| (m.score, i)))
        .collect();
    let total = scored.iter().filter(|x| x.1).count();
    if total == 0 {
        return None;
    }
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    let step = (scored.len() / 60).max(1);
    let mut tp = 0usize;
    let mut points = Vec::new();
    for (i, (_, inl)) in scored.iter().enumerate() {
        tp += *inl as usize;
        if (i + 1) % step == 0 || i + 1 == scored.len() {
            points.push([tp as f64 / total as f64, tp as f64 / (i + 1) as f64]);
        }
    }
    Some(PrCurve {
        name: name.into(),
        points,
    })
}

/// A view's depth frame and display-point visibility (see [`view_depth_and_visibility`]).
pub type ViewExtras = Arc<(RgbImage, Vec<u8>)>;
/// The worker's memo of [`ViewExtras`], keyed by the hash of (depth file, camera, display
/// cloud): a re-fusion (temperature, fusion mode) shows the same views and must not redo them.
pub type ViewMemo = Lru<blake3::Hash, ViewExtras>;
/// Views a [`ViewMemo`] keeps (K per side for a couple of pairs).
pub const VIEW_MEMO: usize = 16;

/// The depth frame of a view as the WFM saw it (the depth video's grey inverse depth) and, per
/// display point of its scan, 0 outside the view, 1 occluded, 2 visible; from `memo` when it
/// holds them.
fn view_depth_and_visibility(
    memo: &mut ViewMemo,
    depth_path: &std::path::Path,
    cam: &ViewCamera,
    cloud: &[[f32; 3]],
    cloud_key: &blake3::Hash,
) -> Option<ViewExtras> {
    let mut h = blake3::Hasher::new();
    h.update(depth_path.as_os_str().as_encoded_bytes());
    for x in cam.cloud_from_camera.to_homogeneous().iter() {
        h.update(&x.to_le_bytes());
    }
    h.update(format!("{:?}", cam.camera).as_bytes());
    h.update(cloud_key.as_bytes());
    let key = h.finalize();
    if let Some(hit) = memo.get(&key) {
        return Some(hit.clone());
    }
    // A missing or unreadable depth frame leaves the view without its depth toggle; the
    // pipeline already read the same file, so this is not expected.
    let d = crate::io::depth_png::read_depth_png(depth_path).ok()?;
    let g =
        crate::wfm::depth_video::gray_to_rgb(&crate::wfm::depth_video::encode_depth_frame_clip(
            &d,
            crate::pipeline::image_branch::depth_video_clip(&cam.camera),
        ));
    let pts: Vec<Point3<f32>> = cloud
        .iter()
        .map(|p| Point3::new(p[0], p[1], p[2]))
        .collect();
    let camera_from_cloud = cam.cloud_from_camera.inverse();
    let visible = cam.camera.visibility(&pts, &camera_from_cloud);
    let (w, h) = cam.camera.size();
    let state = pts
        .iter()
        .zip(&visible)
        .map(|(p, &vis)| {
            if vis {
                return 2;
            }
            let inside = cam
                .camera
                .project(&(camera_from_cloud * p.cast::<f64>()))
                .is_some_and(|(u, v)| {
                    u >= -0.5 && v >= -0.5 && u < w as f64 - 0.5 && v < h as f64 - 0.5
                });
            // Behind a pinhole camera nothing projects; in front and inside but not seen: occluded.
            u8::from(inside)
        })
        .collect();
    let out: ViewExtras = Arc::new((
        RgbImage {
            width: g.width(),
            height: g.height(),
            pixels: g.into_raw(),
        },
        state,
    ));
    memo.insert(key, out.clone());
    Some(out)
}

/// Converts a registration result and its pair into the inspector's model. `pairs` is the
/// pair browser (the current pair's row is updated here); `views` is the caller's memo of the
/// views' depth frames and visibility.
pub fn result_to_model(
    pair: &ScanPair,
    result: &RegistrationResult,
    fusion_label: &str,
    mut pairs: Vec<PairEntry>,
    views: &mut ViewMemo,
) -> InspectorModel {
    let source = display_cloud(
        &result.source_keypoints,
        &pair.source.cloud.points,
        DISPLAY_POINTS,
    );
    let target = display_cloud(
        &result.target_keypoints,
        &pair.target.cloud.points,
        DISPLAY_POINTS,
    );
    let gt = pair.gt_target_from_source;
    let mut survived = vec![false; result.correspondences.len()];
    for &i in &result.inliers {
        if let Some(s) = survived.get_mut(i) {
            *s = true;
        }
    }
    let matches: Vec<MatchInfo> = result
        .correspondences
        .iter()
        .enumerate()
        .filter_map(|(ci, c)| {
            let (s, t) = (c.src as usize, c.tgt as usize);
            let sp = result.source_keypoints.get(s)?;
            let tp = result.target_keypoints.get(t)?;
            let inlier_gt = gt.map(|g| {
                let q = g * sp.cast::<f64>();
                (q - tp.cast::<f64>()).norm() < result.gt_inlier_threshold_m
            });
            Some(MatchInfo {
                src: s,
                tgt: t,
                score: c.score.clamp(0.0, 1.0),
                inlier_gt,
                branch: if result.image_branch.is_some() {
                    Branch::Both
                } else {
                    Branch::Geometry
                },
                survived: Some(survived[ci]),
            })
        })
        .collect();

    let (source_views, target_views, note) =
        view_images(result.image.as_ref(), &matches, &source, &target, views);

    let stages = result
        .timings
        .iter()
        .map(|t| StageInfo {
            name: t.stage.clone(),
            stage: t.name,
            state: if t.status == "cached" {
                StageState::Cached
            } else {
                StageState::Done
            },
            time_ms: Some(t.ms),
            // timed inside the worker's "load + register" / "re-fuse from memory" row
            role: StageRole::Part,
        })
        .collect();

    let current = match pairs.iter().position(|p| p.id == result.pair_id) {
        Some(i) => i,
        None => {
            pairs.push(PairEntry::pending(result.pair_id.clone(), ""));
            pairs.len() - 1
        }
    };
    fill_row(&mut pairs[current], result);

    let plots = PlotData {
        pr_curves: pr_curve(fusion_label, &matches).into_iter().collect(),
        ..Default::default()
    };
    InspectorModel {
        pairs,
        current_pair: Some(current),
        source,
        target,
        initial: Isometry3::identity(),
        estimated: Some(result.estimate),
        ground_truth: gt,
        matches,
        gt_inlier_m: result.gt_inlier_threshold_m,
        source_views,
        target_views,
        posteriors: Vec::new(),
        default_posterior: None,
        stages,
        plots,
        generation_missing: None,
        image_branch_note: note,
        convention_warning: result.convention.as_ref().and_then(|c| c.warning.clone()),
        fusion_note: result.fusion_provenance(),
        hypotheses: None,
        criteria_note: result.metrics.as_ref().map(criteria_note),
        scale_note: result.scales.as_ref().map(|s| s.provenance()),
        preview_note: None,
        branches_ran: None,
        settings: None,
        demo_protocol: None,
        scene_prompt: None,
    }
}

/// "success (RRE ≤ 5°, RTE ≤ 2 m); also RRE ≤ 5°, RTE ≤ 0.6 m: fails": the result's outcome
/// under the run's criterion and its second one, as `register` prints them.
pub fn criteria_note(m: &crate::metrics::PairMetrics) -> String {
    let word = |ok: bool| if ok { "success" } else { "fails" };
    let mut s = format!("{} ({})", word(m.success), m.criterion.label());
    if let Some(a) = &m.also {
        s.push_str(&format!(
            "; also {}: {}",
            a.criterion.label(),
            word(a.success)
        ));
    }
    s
}

/// The views of both scans as the model shows them (generated image, depth frame, visibility
/// of the display points, match pixels), and a note when there are none.
fn view_images(
    image: Option<&ImageBranchOutput>,
    matches: &[MatchInfo],
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    memo: &mut ViewMemo,
) -> (Vec<ViewImage>, Vec<ViewImage>, Option<String>) {
    // One content hash per display cloud keys the views' visibility memo (hashed as one
    // buffer: per-value updates cost more than the fusion they follow).
    let cloud_key = |c: &[[f32; 3]]| {
        let mut bytes = Vec::with_capacity(c.len() * 12);
        for x in c.iter().flatten() {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
        blake3::hash(&bytes)
    };
    match image {
        Some(img) => {
            // only views need it (geometry-only runs skip hashing both clouds)
            let (source_key, target_key) = (cloud_key(source), cloud_key(target));
            let prov = &img.provenance;
            let mut mk = |views: &[crate::pipeline::ViewInfo],
                          links: &[Option<crate::vfm::lift::PixelLink>],
                          is_src: bool| {
                views
                    .iter()
                    .enumerate()
                    .map(|(vi, v)| {
                        let match_pixels = matches
                            .iter()
                            .map(|m| {
                                let k = if is_src { m.src } else { m.tgt };
                                links
                                    .get(k)
                                    .copied()
                                    .flatten()
                                    .filter(|l| l.view as usize == vi)
                                    .map(|l| [l.u as f32, l.v as f32])
                            })
                            .collect();
                        // `v.label` is "backend | prompt | cache <hash>": keep the cache part
                        let entry = v
                            .label
                            .rsplit(" | ")
                            .next()
                            .filter(|e| e.starts_with("cache"))
                            .unwrap_or(v.label.as_str());
                        let cam = v.scan_from_camera.map(|pose| ViewCamera {
                            cloud_from_camera: pose,
                            camera: v.camera.clone(),
                        });
                        let (cloud, cloud_key) = if is_src {
                            (source, &source_key)
                        } else {
                            (target, &target_key)
                        };
                        let shown = v
                            .depth_path
                            .as_deref()
                            .zip(cam.as_ref())
                            .and_then(|(p, c)| {
                                view_depth_and_visibility(memo, p, c, cloud, cloud_key)
                            });
                        ViewImage {
                            label: ViewLabel {
                                backend: prov.model.clone(),
                                prompt: prov.prompt.clone(),
                                cache_entry: format!(
                                    "{entry} · generated frame {} · depth frame {} ({})",
                                    v.generated_index,
                                    v.depth_index,
                                    v.camera.name()
                                ),
                            },
                            rgb: RgbImage {
                                width: v.image.width(),
                                height: v.image.height(),
                                pixels: v.image.as_raw().clone(),
                            },
                            depth: shown.as_ref().map(|d| d.0.clone()),
                            camera: cam,
                            point_state: shown.map(|d| d.1.clone()).unwrap_or_default(),
                            match_pixels,
                        }
                    })
                    .collect::<Vec<_>>()
            };
            let s = mk(&img.source_views, &img.source_links, true);
            let t = mk(&img.target_views, &img.target_links, false);
            let note = if s.is_empty() && t.is_empty() {
                Some("image branch ran but selected no views".to_string())
            } else {
                None
            };
            (s, t, note)
        }
        None => (Vec::new(), Vec::new(), Some(IMAGE_BRANCH_OFF.to_string())),
    }
}

/// The pair browser's row of a registered pair: status, RRE, RTE, success, inlier ratio,
/// correspondences, time, criteria and the official recall's RMSE from `result`.
pub fn fill_row(row: &mut PairEntry, result: &RegistrationResult) {
    row.status = PairStatus::Done;
    row.rre_deg = result.metrics.as_ref().map(|m| m.rre_deg);
    row.rte_m = result.metrics.as_ref().map(|m| m.rte_m);
    row.success = result.metrics.as_ref().map(|m| m.success);
    row.inlier_ratio = result.metrics.as_ref().map(|m| m.inlier_ratio);
    row.correspondences = Some(result.n_correspondences);
    row.time_ms = Some(result.total_ms);
    row.criterion = result.metrics.as_ref().map(|m| m.criterion);
    row.also = result.metrics.as_ref().and_then(|m| m.also);
    // the official recall's RMSE, as `bench` computes it (the manifest's GT and gt.info)
    row.rmse_m = row.rmse_ref.as_ref().map(|r| {
        crate::metrics::rmse_3dmatch(&result.estimate, &r.gt_target_from_source, &r.information)
    });
}

fn top_indices(v: &[f32], n: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    let n = n.min(idx.len());
    if n == 0 {
        return Vec::new();
    }
    idx.select_nth_unstable_by(n - 1, |&a, &b| v[b].total_cmp(&v[a]));
    idx.truncate(n);
    idx.sort_by(|&a, &b| v[b].total_cmp(&v[a]));
    idx
}

/// Branch posteriors of source keypoint `src` over the target keypoints: row `src` of the
/// posteriors `match_then_fuse` forms from the kept similarities `sims` with `fusion`
/// ([`crate::fusion::posterior_row`]; without the image branch the mode is geometry only).
/// Points without a pixel have an image posterior of 0, as in the pipeline. Candidates: the
/// most likely under the fused, image and geometric posteriors, plus the ground-truth target.
pub fn point_posterior(
    inputs: &FusionInputs,
    sims: &Similarities,
    image: Option<&ImageBranchOutput>,
    fusion: &crate::fusion::FusionParams,
    src: usize,
    gt: Option<&Isometry3<f64>>,
    survived: Option<bool>,
) -> crate::Result<Posterior> {
    let (sg, tg) = (&inputs.source_geo, &inputs.target_geo);
    let mut fusion = *fusion;
    if sims.image.is_none() {
        fusion.mode = FusionMode::GeometryOnly;
    }
    let row = crate::fusion::posterior_row(
        sims.image
            .as_ref()
            .map(|(s, rv, cv)| (s, Some(rv.as_slice()), Some(cv.as_slice()))),
        Some(&sims.geo),
        &fusion,
        src,
    )?;
    let p_geo = row.geometric.unwrap_or_default();
    let p_img = row.image;
    let fused = row.fused;
    let gt_target = gt.map(|g| {
        let q = g * sg.keypoints.points[src].cast::<f64>();
        let mut best = (0, f64::INFINITY);
        for (j, t) in tg.keypoints.points.iter().enumerate() {
            let d = (t.cast::<f64>() - q).norm_squared();
            if d < best.1 {
                best = (j, d);
            }
        }
        best.0
    });
    let mut candidates = top_indices(&fused, POSTERIOR_CANDIDATES);
    let mut seen: std::collections::HashSet<usize> = candidates.iter().copied().collect();
    let extra = POSTERIOR_CANDIDATES / 4;
    let mut more = top_indices(&p_geo, extra);
    if let Some(pi) = &p_img {
        more.extend(top_indices(pi, extra));
    }
    more.extend(gt_target);
    for j in more {
        if seen.insert(j) {
            candidates.push(j);
        }
    }
    let link =
        |links: &[Option<crate::vfm::lift::PixelLink>], j: usize| links.get(j).copied().flatten();
    let (source_view, source_pixel) = match image.and_then(|o| link(&o.source_links, src)) {
        Some(l) => (l.view as usize, Some([l.u as f32, l.v as f32])),
        None => (0, None),
    };
    // the target view of the ground-truth point, else of the most likely candidate
    let target_view = image
        .and_then(|o| {
            gt_target
                .into_iter()
                .chain(candidates.first().copied())
                .find_map(|j| link(&o.target_links, j))
        })
        .map_or(0, |l| l.view as usize);
    let candidate_pixels = candidates
        .iter()
        .map(|&j| {
            image
                .and_then(|o| link(&o.target_links, j))
                .filter(|l| l.view as usize == target_view)
                .map(|l| [l.u as f32, l.v as f32])
        })
        .collect();
    let pick = |v: &[f32]| candidates.iter().map(|&j| v[j]).collect::<Vec<f32>>();
    Ok(Posterior {
        source_point: src,
        source_pixel,
        source_view,
        image: p_img.as_ref().map(|p| pick(p)).unwrap_or_default(),
        geometric: pick(&p_geo),
        fused: pick(&fused),
        candidates,
        candidate_pixels,
        target_view,
        gt_target,
        survived,
        reason: String::new(),
    })
}

/// The source point the posterior tab opens on after a run, and why: the strongest selected
/// match that fails under the ground truth (its target more than `gt_inlier_m` from where the
/// GT puts the source point), else the strongest match. None without matches.
pub fn default_posterior_point(matches: &[MatchInfo], gt_inlier_m: f64) -> Option<(usize, String)> {
    let within = crate::app::model::distance_label(gt_inlier_m);
    let strongest = |keep: &dyn Fn(&MatchInfo) -> bool| {
        matches
            .iter()
            .enumerate()
            .filter(|(_, m)| keep(m))
            .max_by(|(i, a), (j, b)| a.score.total_cmp(&b.score).then(j.cmp(i)))
    };
    let rank = |m: &MatchInfo| 1 + matches.iter().filter(|o| o.score > m.score).count();
    let n = matches.len();
    if let Some((_, m)) = strongest(&|m| m.inlier_gt == Some(false)) {
        let wrong = matches
            .iter()
            .filter(|m| m.inlier_gt == Some(false))
            .count();
        return Some((
            m.src,
            format!(
                "opened on the strongest selected match that fails under GT: source #{} -> target #{}, \
                 fused score {:.3} (rank {} of {n}; {wrong} of {n} matches are > {within} off GT)",
                m.src,
                m.tgt,
                m.score,
                rank(m)
            ),
        ));
    }
    let (_, m) = strongest(&|_| true)?;
    let why = if matches.iter().any(|m| m.inlier_gt.is_some()) {
        format!("every selected match is within {within} of GT")
    } else {
        "no ground truth for this pair".to_string()
    };
    Some((
        m.src,
        format!(
            "opened on the strongest selected match ({why}): source #{} -> target #{}, fused \
             score {:.3}",
            m.src, m.tgt, m.score
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(src: usize, score: f32, inlier: Option<bool>) -> MatchInfo {
        MatchInfo {
            src,
            tgt: src + 100,
            score,
            inlier_gt: inlier,
            branch: Branch::Both,
            survived: None,
        }
    }

    #[test]
    fn default_point_is_the_strongest_wrong_match_else_the_strongest() {
        let ms = [
            m(1, 0.9, Some(true)),
            m(2, 0.5, Some(false)),
            m(3, 0.7, Some(false)),
            m(4, 0.95, Some(true)),
        ];
        let (src, why) = default_posterior_point(&ms, 0.1).unwrap();
        assert_eq!(src, 3);
        assert!(
            why.contains("fails under GT") && why.contains("rank 3 of 4"),
            "{why}"
        );
        assert!(why.contains("2 of 4"), "{why}");
        let ok = [m(1, 0.9, Some(true)), m(4, 0.95, Some(true))];
        let (src, why) = default_posterior_point(&ok, 0.1).unwrap();
        assert_eq!(src, 4);
        assert!(why.contains("within 10 cm"), "{why}");
        let (src, why) = default_posterior_point(&[m(7, 0.2, None), m(8, 0.1, None)], 0.1).unwrap();
        assert_eq!(src, 7);
        assert!(why.contains("no ground truth"), "{why}");
        assert!(default_posterior_point(&[], 0.1).is_none());
    }
}
