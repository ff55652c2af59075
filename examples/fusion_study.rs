//! The study of the fusion rules on development pairs (docs/ablation.md, "A fusion that never
//! loses to its best branch"): for every pair of a manifest, the image branch's inputs are
//! computed once (through the stage cache), then every candidate of the protocol is estimated
//! from them and written to one JSON line per pair:
//! the geometry-alone, Noisy-AND and image-alone poses with their fit on the union of
//! {geometry, Noisy-AND} and of all three sets, on each branch's own set, SC2-PCR on the union
//! of the Noisy-AND and geometry sets (b, the `union` mode), and each pose's free-space
//! (visibility) consistency with both scans' depth views (fourth round), and (a probe for a
//! later round, not a rule of any round so far) each pose after point-to-plane ICP on the
//! keypoint clouds, at the inlier threshold θ alone (`icp1_*`) and coarse to fine at 4θ, 2θ, θ
//! (`icp3_*`). The first round's
//! candidate (c) is no longer computed. `studies/fusion/rounds.py` applies each round's rules
//! and its decision rule to these lines.
//!
//! ```sh
//! cargo run --example fusion_study -- assets/manifests/redkitchen-dev.toml --wfm oracle \
//!     --cache-dir DIR --out dev-oracle.jsonl [--clouds-only] [--split S]
//! ```
//!
//! Every option not named is the default of the parameter types (ALIKE-t, K = 4, row softmax
//! τ 0.1, mutual NN for the fused sets, SC2-PCR), as `cgenreg bench --vfm alike` runs it.

use cgenreg::camera::visibility::visibility;
use cgenreg::dataset::manifest::Dataset;
use cgenreg::estimate::estimate_pose;
use cgenreg::fusion::union::merge;
use cgenreg::fusion::Correspondence;
use cgenreg::metrics::{rre_deg, rte_m};
use cgenreg::pipeline::stages::virtual_frames::{with_virtual_frames, FrameStore};
use cgenreg::pipeline::tail::{endpoints, similarities};
use cgenreg::pipeline::union::{
    geometry_params, image_params, mode_correspondences, noisy_and_params,
};
use cgenreg::pipeline::visibility::PairViews;
use cgenreg::pipeline::{ImageBranchParams, Memo, RegisterParams, Registration, VfmSpec, WfmSpec};
use clap::Parser;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};
use serde_json::{json, Value};
use std::io::Write;
use std::path::PathBuf;

#[derive(Parser)]
struct Args {
    manifest: PathBuf,
    /// JSON lines output (appended; pairs already in it are skipped).
    #[arg(long)]
    out: PathBuf,
    /// Drop the sensor frames: each fragment is only its cloud (virtual frames).
    #[arg(long)]
    clouds_only: bool,
    /// Only this split.
    #[arg(long)]
    split: Option<String>,
    /// oracle (the dataset's colour) or builtin (depth shading, virtual frames for clouds).
    #[arg(long, default_value = "oracle")]
    wfm: String,
    /// The stage cache.
    #[arg(long)]
    cache_dir: PathBuf,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a = Args::parse();
    let cache = Some(cgenreg::cache::Cache::open(&a.cache_dir)?);
    let ds = Dataset::load(&a.manifest)?.with_fragment_cache(cache.clone());
    let backend = match a.wfm.as_str() {
        "oracle" => WfmSpec::Oracle,
        "builtin" => WfmSpec::Builtin,
        w => return Err(format!("--wfm {w}: oracle or builtin").into()),
    };
    let params = RegisterParams {
        image: Some(ImageBranchParams {
            backend,
            vfm: VfmSpec::Alike {
                model: cgenreg::vfm::default_model_path("alike-t.onnx"),
            },
            ..Default::default()
        }),
        ..Default::default()
    };
    let done: std::collections::HashSet<String> = std::fs::read_to_string(&a.out)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter_map(|v| v["id"].as_str().map(String::from))
        .collect();
    let mut out = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&a.out)?;
    let memo = Memo::default();
    for spec in ds.select_pairs(a.split.as_deref(), None) {
        if done.contains(&spec.id) {
            continue;
        }
        let t0 = std::time::Instant::now();
        let mut pair = ds.load_pair(&spec.id)?;
        if a.clouds_only {
            pair.source.frames = None;
            pair.target.frames = None;
        }
        let line = match study_pair(&pair, &params, cache.as_ref(), &memo) {
            Ok(mut v) => {
                v["id"] = json!(spec.id);
                v["split"] = json!(spec.split);
                v["time_s"] = json!(t0.elapsed().as_secs_f64());
                v
            }
            Err(e) => json!({"id": spec.id, "split": spec.split, "error": e.to_string()}),
        };
        eprintln!("{}: {:.0} s", spec.id, t0.elapsed().as_secs_f64());
        writeln!(out, "{line}")?;
        out.flush()?;
    }
    Ok(())
}

fn study_pair(
    pair: &cgenreg::dataset::ScanPair,
    params: &cgenreg::pipeline::RegisterParams,
    cache: Option<&cgenreg::cache::Cache>,
    memo: &Memo,
) -> cgenreg::Result<Value> {
    let r = Registration::new(params)
        .cache(cache)
        .memo(memo)
        .keep(true)
        .run(pair)?;
    let inputs = r
        .inputs
        .ok_or_else(|| cgenreg::Error::Missing("the registration kept no inputs".into()))?;
    let gt = pair
        .gt_target_from_source
        .ok_or_else(|| cgenreg::Error::Missing("the study needs ground truth".into()))?;
    let sims = similarities(&inputs)?;
    let set = |f| mode_correspondences(&inputs, Some(&sims), &f);
    let geo = &set(geometry_params(&params.fusion))?;
    let and = &set(noisy_and_params(&params.fusion))?;
    let img = &set(image_params(&params.fusion))?;
    // (b): Noisy-AND's set, then the geometry set's pairs not in it (the `union` mode's merge)
    let b: Vec<Correspondence> = merge(and, geo).0;
    // The depth views of each side (the sensor's frames, or the virtual frames the image branch
    // rendered for a cloud-only scan), for the visibility score of the fourth round.
    let ib = params
        .image
        .as_ref()
        .ok_or_else(|| cgenreg::Error::Missing("the study needs the image branch".into()))?;
    let (framed, _) = with_virtual_frames(&mut FrameStore::new(cache), pair, ib)?;
    let frames = |scan: &cgenreg::dataset::Scan| {
        scan.frames
            .clone()
            .ok_or_else(|| cgenreg::Error::Missing(format!("{}: no depth frames", scan.name)))
    };
    let pair_views = PairViews::new(frames(&framed.source)?, frames(&framed.target)?);
    let [src_views, tgt_views] = pair_views.views()?;
    let theta = params.inlier_threshold_m();
    let (src, tgt) = (&inputs.source_geo, &inputs.target_geo);
    let pts = |u: &[(u32, u32)]| {
        let s: Vec<_> = u
            .iter()
            .map(|&(i, _)| src.keypoints.points[i as usize])
            .collect();
        let t: Vec<_> = u
            .iter()
            .map(|&(_, j)| tgt.keypoints.points[j as usize])
            .collect();
        (s, t)
    };
    let (u2s, u2t) = pts(&union(&[geo, and]));
    let (u3s, u3t) = pts(&union(&[geo, and, img]));
    // Each branch's own set (distinct pairs), for the balanced score of the second round.
    let (gs, gt_) = pts(&union(&[geo]));
    let (as_, at) = pts(&union(&[and]));
    let (is, it) = pts(&union(&[img]));
    // The probe's ICP: target normals by local PCA at twice the keypoint voxel (30 neighbours).
    let tgt_index = cgenreg::geometry::knn::KdIndex::new(&tgt.keypoints.points);
    let tgt_normals = cgenreg::geometry::normals::estimate_normals(
        &tgt.keypoints.points,
        &tgt_index,
        2.0 * params.voxel,
        30,
    );
    let icp = |t0: &Isometry3<f64>, radii: &[f64]| {
        radii.iter().fold(*t0, |t, &d| {
            icp_point_to_plane(
                &src.keypoints.points,
                &tgt.keypoints.points,
                &tgt_normals,
                &tgt_index,
                t,
                d,
            )
        })
    };
    let mut cands = serde_json::Map::new();
    for (name, corr) in [
        ("geometry", geo),
        ("noisy-and", and),
        ("image", img),
        ("union-b", &b),
    ] {
        let (sp, tp, w) = endpoints((src, tgt), corr);
        let v = match estimate_pose(&sp, &tp, &w, &params.estimator) {
            Ok(e) => {
                let t = e.target_from_source;
                let (r, tr) = (rre_deg(&t, &gt), rte_m(&t, &gt));
                let f2 = fit(&t, &u2s, &u2t, theta);
                let f3 = fit(&t, &u3s, &u3t, theta);
                let gt_in = cgenreg::metrics::inlier_ratio(&sp, &tp, &gt, theta)?;
                let fg = fit(&t, &gs, &gt_, theta).consensus;
                let fa = fit(&t, &as_, &at, theta).consensus;
                let fi = fit(&t, &is, &it, theta).consensus;
                // Source keypoints against the target's views, target keypoints against the
                // source's views (under the inverse pose).
                let vst = visibility(&src.keypoints.points, &t, &tgt_views, theta);
                let vts = visibility(&tgt.keypoints.points, &t.inverse(), &src_views, theta);
                let t1 = icp(&t, &[theta]);
                let t3 = icp(&t, &[4.0 * theta, 2.0 * theta, theta]);
                let (r1, tr1) = (rre_deg(&t1, &gt), rte_m(&t1, &gt));
                let (r3, tr3) = (rre_deg(&t3, &gt), rte_m(&t3, &gt));
                json!({"icp1_rre": r1, "icp1_rte": tr1, "icp1_ok": r1 <= 15.0 && tr1 <= 0.30,
                       "icp3_rre": r3, "icp3_rte": tr3, "icp3_ok": r3 <= 15.0 && tr3 <= 0.30,
                       "fit_g": fg, "fit_a": fa, "fit_i": fi,
                       "vis_st": [vst.consistent, vst.conflict, vst.unseen],
                       "vis_ts": [vts.consistent, vts.conflict, vts.unseen],
                       "vis": (vst + vts).score(),
                       "n": corr.len(), "est_inliers": e.inliers.len(), "method": e.method,
                       "rre": r, "rte": tr, "ok": r <= 15.0 && tr <= 0.30,
                       "fit2": f2.consensus, "msac2": f2.msac,
                       "fit3": f3.consensus, "msac3": f3.msac, "gt_ir": gt_in})
            }
            Err(e) => json!({"n": corr.len(), "error": e.to_string()}),
        };
        cands.insert(name.into(), v);
    }
    Ok(
        json!({"n_src": src.keypoints.len(), "n_tgt": tgt.keypoints.len(),
              "u2": u2s.len(), "u3": u3s.len(),
              "n_g": gs.len(), "n_a": as_.len(), "n_i": is.len(), "candidates": cands}),
    )
}

/// A pose's fit on a branch-neutral set: (pairs within `theta`, Σ min(r², θ²) / θ²).
struct Fit {
    consensus: usize,
    msac: f64,
}

fn fit(
    t: &nalgebra::Isometry3<f64>,
    src: &[nalgebra::Point3<f32>],
    tgt: &[nalgebra::Point3<f32>],
    theta: f64,
) -> Fit {
    let t2 = theta * theta;
    let (mut consensus, mut msac) = (0usize, 0.0f64);
    for (s, q) in src.iter().zip(tgt) {
        let r2 = (t * s.cast::<f64>() - q.cast::<f64>()).norm_squared();
        if r2 <= t2 {
            consensus += 1;
            msac += r2 / t2;
        } else {
            msac += 1.0;
        }
    }
    Fit { consensus, msac }
}

/// The distinct (source, target) pairs of the sets, in first-seen order.
fn union(sets: &[&[Correspondence]]) -> Vec<(u32, u32)> {
    let mut seen = std::collections::HashSet::new();
    sets.iter()
        .flat_map(|s| s.iter())
        .filter(|c| seen.insert((c.src, c.tgt)))
        .map(|c| (c.src, c.tgt))
        .collect()
}

/// Point-to-plane ICP (Gauss-Newton on the linearised rotation, at most 30 iterations): each
/// moved source point paired with its nearest target point within `max_dist` that has a normal;
/// stops when an update moves less than 1e-6 (rad + m) or fewer than 6 pairs remain.
fn icp_point_to_plane(
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    normals: &[Vector3<f32>],
    index: &cgenreg::geometry::knn::KdIndex,
    init: Isometry3<f64>,
    max_dist: f64,
) -> Isometry3<f64> {
    let mut t = init;
    for _ in 0..30 {
        let mut a = Matrix6::<f64>::zeros();
        let mut b = Vector6::<f64>::zeros();
        let mut n_pairs = 0usize;
        for p in src {
            let q = t * p.cast::<f64>();
            let Some((j, d)) = index.nearest(&q.cast::<f32>()) else {
                continue;
            };
            let n = normals[j].cast::<f64>();
            if f64::from(d) > max_dist || n.norm() == 0.0 {
                continue;
            }
            let r = n.dot(&(q - tgt[j].cast::<f64>()));
            let c = q.coords.cross(&n);
            let jac = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
            a += jac * jac.transpose();
            b += jac * r;
            n_pairs += 1;
        }
        if n_pairs < 6 {
            break;
        }
        let Some(x) = a.cholesky().map(|ch| ch.solve(&(-b))) else {
            break;
        };
        let rot = UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2]));
        let step = Isometry3::from_parts(Translation3::new(x[3], x[4], x[5]), rot);
        t = step * t;
        if x.norm() < 1e-6 {
            break;
        }
    }
    t
}
