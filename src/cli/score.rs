//! `cgenreg score`: another method's poses scored exactly as `bench` scores cgenreg's, with the
//! same formulas (RRE / RTE under the manifest's criteria, the official 3DMatch RMSE recall over
//! gt.info, mean and median RE / TE), written as a bench run file so that `table` and `diff`
//! compare the method with cgenreg pair by pair.
//!
//! The poses file is JSON: `{"pairs": [{"id": .., "target_from_source": 4x4 | null, "time_s": ..}]}`
//! (row-major, `p_target = T p_source`, the manifest's pair ids; null: the method gave no pose),
//! or a file of several runs, `{"runs": [{"method": .., "pairs": [..]}]}` (what
//! `scripts/peers.sh --json` writes), one of which `--run` picks.

use super::bench::{
    log_line, print_field_table, print_table, progress_bar, rmse_counted, selection,
};
use crate::dataset::manifest::{Dataset, PairSpec};
use crate::error::{Error, Result};
use crate::metrics::{rmse_3dmatch, PairMetrics, SuccessCriteria};
use crate::pipeline::shard::{
    run_pending, PairRecord, Progress, ResumeMode, RunIdentity, Shard, DONE, FAILED,
};
use crate::report::bench_file::{bench_json, field_summaries, rows_of, summarise, PairRow};
use clap::Args;
use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct ScoreArgs {
    /// Dataset manifest (TOML): the pairs, their ground truth and gt.info, and the success
    /// criteria of its preset.
    pub manifest: PathBuf,
    /// The method's poses (JSON): `pairs: [{id, target_from_source (4x4, row-major; null: no
    /// pose), time_s}]`, or `runs: [{method, pairs}]` with --run.
    pub poses: PathBuf,
    /// Which run of a file of several runs (0-based, in the file's order).
    #[arg(long)]
    pub run: Option<usize>,
    /// Only pairs of this split (e.g. 3DMatch, 3DLoMatch); default all, reported per split.
    #[arg(long)]
    pub split: Option<String>,
    /// Write the scored pairs as a bench run file (for `table` and `diff`).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Replace an existing --json file even when it is not a cgenreg run file.
    #[arg(long)]
    pub force: bool,
}

/// One pair of the poses file.
#[derive(Clone, Debug, PartialEq)]
pub struct GivenPose {
    /// None: the method gave no pose for the pair (a failure).
    pub target_from_source: Option<Isometry3<f64>>,
    pub time_s: Option<f64>,
}

/// The method's name (when the file names it) and its poses by pair id.
pub type Poses = (Option<String>, HashMap<String, GivenPose>);

/// Reads a poses file; every error names the file, the pair and the field.
pub fn read_poses(path: &Path, run: Option<usize>) -> Result<Poses> {
    let bytes = crate::io::limits::read_file(path)?;
    let v: Value = serde_json::from_slice(&bytes).map_err(|e| {
        Error::Invalid(format!(
            "{}: not JSON ({e}); expected a poses file",
            path.display()
        ))
    })?;
    let bad = |what: String| Error::Invalid(format!("{}: {what}", path.display()));
    let (method, pairs) = match (v.get("runs"), v.get("pairs")) {
        (Some(Value::Array(runs)), _) => {
            let k = match (run, runs.len()) {
                (Some(k), n) if k < n => k,
                (Some(k), n) => return Err(bad(format!("--run {k}, but the file has {n} runs"))),
                (None, 1) => 0,
                (None, n) => {
                    let names: Vec<String> = runs
                        .iter()
                        .enumerate()
                        .map(|(i, r)| {
                            format!(
                                "{i}: {}",
                                r.get("method").and_then(Value::as_str).unwrap_or("?")
                            )
                        })
                        .collect();
                    return Err(bad(format!(
                        "{n} runs; pick one with --run ({})",
                        names.join("; ")
                    )));
                }
            };
            let r = &runs[k];
            let method = r.get("method").and_then(Value::as_str).map(str::to_string);
            match r.get("pairs") {
                Some(Value::Array(p)) => (method, p.clone()),
                _ => return Err(bad(format!("runs[{k}].pairs: expected an array of pairs"))),
            }
        }
        (_, Some(Value::Array(p))) => (
            v.get("method").and_then(Value::as_str).map(str::to_string),
            p.clone(),
        ),
        _ => {
            return Err(bad(
                "expected `pairs` (an array) or `runs` at the top level".into(),
            ))
        }
    };
    let mut out = HashMap::new();
    for (k, p) in pairs.iter().enumerate() {
        let id = p
            .get("id")
            .and_then(Value::as_str)
            .ok_or_else(|| bad(format!("pairs[{k}].id: expected a string")))?;
        let field = |f: &str| format!("pair {id} (pairs[{k}]).{f}");
        let target_from_source = match p.get("target_from_source") {
            None | Some(Value::Null) => None,
            Some(m) => Some(
                isometry(m)
                    .map_err(|why| bad(format!("{}: {why}", field("target_from_source"))))?,
            ),
        };
        let time_s = match p.get("time_s") {
            None | Some(Value::Null) => None,
            Some(t) => Some(
                t.as_f64()
                    .filter(|t| t.is_finite() && *t >= 0.0)
                    .ok_or_else(|| bad(format!("{}: expected seconds >= 0", field("time_s"))))?,
            ),
        };
        let given = GivenPose {
            target_from_source,
            time_s,
        };
        if out.insert(id.to_string(), given).is_some() {
            return Err(bad(format!("{}: listed twice", field("id"))));
        }
    }
    Ok((method, out))
}

/// A 4x4 row-major rigid transform: finite, last row 0 0 0 1, a rotation (orthonormal to 1e-4,
/// determinant +1); the rotation is re-orthonormalised before use.
fn isometry(m: &Value) -> std::result::Result<Isometry3<f64>, String> {
    let expected = "expected a 4x4 row-major rigid transform";
    let rows = m.as_array().filter(|r| r.len() == 4).ok_or(expected)?;
    let mut a = Matrix4::<f64>::zeros();
    for (i, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|r| r.len() == 4).ok_or(expected)?;
        for (j, x) in row.iter().enumerate() {
            a[(i, j)] = x
                .as_f64()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{expected}; entry ({i}, {j}) is not a finite number"))?;
        }
    }
    let last = [a[(3, 0)], a[(3, 1)], a[(3, 2)], a[(3, 3)]];
    if last
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(x, e)| (x - e).abs() > 1e-9)
    {
        return Err(format!(
            "{expected}; the last row is {last:?}, not [0, 0, 0, 1]"
        ));
    }
    let r: Matrix3<f64> = a.fixed_view::<3, 3>(0, 0).into_owned();
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if off > 1e-4 || r.determinant() <= 0.0 {
        return Err(format!(
            "{expected}; the 3x3 block is not a rotation (|RᵀR - I| = {off:.2e}, det = {:.4})",
            r.determinant()
        ));
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Ok(Isometry3::from_parts(
        Translation3::new(a[(0, 3)], a[(1, 3)], a[(2, 3)]),
        rot,
    ))
}

/// One pair scored: the row `bench` would write for this pose.
pub fn score_pair(ds: &Dataset, spec: &PairSpec, given: Option<&GivenPose>) -> PairRow {
    let rmse_counted = rmse_counted(spec, false);
    let time_s = given.and_then(|g| g.time_s).unwrap_or(0.0);
    let failed = |why: &str| PairRow {
        scene: spec.scene.clone(),
        rmse_counted,
        ..PairRow::failed(&spec.id, &spec.split, why, time_s)
    };
    let Some(gt) = &spec.gt_target_from_source else {
        return failed("the manifest gives this pair no ground truth");
    };
    let Some(est) = given.and_then(|g| g.target_from_source) else {
        return failed(if given.is_some() {
            "the method gave no pose"
        } else {
            "not in the poses file"
        });
    };
    let criteria: SuccessCriteria = ds.preset_of(&spec.id).unwrap_or_default().success();
    let m = PairMetrics::judged(&est, gt, f64::NAN, &criteria);
    PairRow {
        id: spec.id.clone(),
        split: spec.split.clone(),
        source: spec.source.clone(),
        target: spec.target.clone(),
        rre_deg: Some(m.rre_deg),
        rte_m: Some(m.rte_m),
        inlier_ratio: None,
        success: Some(m.success),
        time_s,
        error: None,
        criterion: Some(m.criterion),
        also: m.also,
        gt_distance_m: Some(gt.translation.vector.norm()),
        fusion: None,
        scales: None,
        scene: spec.scene.clone(),
        rmse_counted,
        rmse_m: match &spec.gt_info {
            Some(info) if rmse_counted => Some(rmse_3dmatch(&est, gt, &info.information)),
            _ => None,
        },
    }
}

pub fn run(a: ScoreArgs) -> Result<()> {
    let ScoreArgs {
        manifest,
        poses,
        run,
        split,
        json,
        force,
    } = a;
    let ds = Dataset::load(&manifest)?;
    let specs = selection(&ds, &manifest, split.as_deref(), None)?;
    if let Some(p) = &json {
        crate::io::output::prepare(p, crate::io::output::OutputKind::RunJson, force)?;
    }
    let (method, given) = read_poses(&poses, run)?;
    let missing = specs.iter().filter(|s| !given.contains_key(&s.id)).count();
    if missing == specs.len() {
        return Err(Error::Invalid(format!(
            "{}: none of the {} selected pairs of {} is in it (pair ids look like `{}`)",
            poses.display(),
            specs.len(),
            manifest.display(),
            specs.first().map(|s| s.id.as_str()).unwrap_or("?")
        )));
    }
    let params = serde_json::json!({
        "scored": poses.display().to_string(),
        "run": run,
        "method": method,
    });
    let identity = RunIdentity::new(
        "score",
        &manifest,
        split.as_deref(),
        None,
        params,
        1,
        specs.iter().map(|s| s.id.clone()).collect(),
    )?;
    let (mut progress, _) =
        Progress::start(identity, Shard::ALL, json.as_deref(), ResumeMode::Restart)?;
    let bar = progress_bar(specs.len());
    let mut score = |pos: usize, id: &str| -> Result<PairRecord> {
        let row = score_pair(&ds, specs[pos], given.get(id));
        bar.inc(1);
        Ok(PairRecord {
            id: id.to_string(),
            status: if row.error.is_some() { FAILED } else { DONE }.into(),
            error: row.error.clone(),
            time_s: row.time_s,
            stages: Vec::new(),
            result: serde_json::to_value(&row)
                .map_err(|e| Error::Encode(format!("serialising a row: {e}")))?,
        })
    };
    // as bench records a pair that failed: with its scene and whether the official recall counts it
    let failed_result = |pos: usize, why: &str| {
        let spec = specs[pos];
        serde_json::to_value(PairRow {
            scene: spec.scene.clone(),
            rmse_counted: rmse_counted(spec, false),
            ..PairRow::failed(&spec.id, &spec.split, why, 0.0)
        })
        .unwrap_or_default()
    };
    let written = run_pending(
        &mut progress,
        &bench_json,
        &mut score,
        &failed_result,
        &mut |l| log_line(&bar, l),
    );
    bar.finish_and_clear();
    let rows = rows_of(&progress.run_file())?;
    if let Some(m) = &method {
        outln!("{m}, scored on {}", manifest.display());
    }
    print_table(&summarise(&rows));
    outln!();
    print_field_table(&field_summaries(&rows));
    if missing > 0 {
        eprintln!(
            "{missing} of {} pairs are not in {} (scored as failures)",
            specs.len(),
            poses.display()
        );
    }
    written?;
    if let Some(p) = &json {
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}
