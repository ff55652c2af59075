//! `cgenreg table`: several `bench --json` files as one table in the layout of the paper's
//! Table 4 (VFM | geometric features | fusion | rotation accuracy and error | translation
//! accuracy and error), one row per file and split. Rows are labelled from each file's own
//! parameters, so a row can never claim a backend it did not run.

use crate::error::{Error, Result};
use clap::Args;
use serde_json::Value;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct TableArgs {
    /// `cgenreg bench --json` outputs, one row each (per split).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Only this split (e.g. 3DMatch).
    #[arg(long)]
    pub split: Option<String>,
}

fn field<'a>(path: &Path, v: &'a Value, ptr: &str) -> Result<&'a Value> {
    v.pointer(ptr).ok_or_else(|| {
        Error::format(
            path,
            ptr,
            "a field of `cgenreg bench --json` output",
            "missing",
        )
    })
}

/// (WFM + VFM, geometric features, fusion) of a run, from its parameters.
fn row_label(path: &Path, params: &Value) -> Result<(String, String, String)> {
    let geo = match field(path, params, "/geo_features/kind")?.as_str() {
        Some("fpfh") => "FPFH".to_string(),
        Some("files") => "learned (files)".to_string(),
        Some("geo-transformer-pkl") => "GeoTransformer (pkl)".to_string(),
        Some("spinnet") => format!(
            "SpinNet {} ({} keypoints)",
            field(path, params, "/geo_features/protocol")?
                .as_str()
                .unwrap_or("?"),
            field(path, params, "/geo_features/keypoints")?
        ),
        other => format!("{other:?}"),
    };
    let mode = field(path, params, "/fusion/mode")?
        .as_str()
        .unwrap_or("?")
        .to_string();
    let image = params.get("image").filter(|v| !v.is_null());
    Ok(match image {
        None => ("—".into(), geo, "—".into()),
        Some(ib) => {
            let wfm = match field(path, ib, "/backend/kind")?.as_str() {
                Some("oracle") => "oracle RGB".to_string(),
                Some("builtin") => "built-in depth shading (not a WFM)".to_string(),
                Some("cached") => "Cosmos (cached)".to_string(),
                Some("cosmos") => "Cosmos (run)".to_string(),
                other => format!("{other:?}"),
            };
            let kind = field(path, ib, "/vfm/kind")?.as_str();
            let vfm = match kind {
                Some("xfeat") => "XFeat",
                Some("disk") => "DISK",
                Some("alike") => "ALIKE",
                Some("mast3r") => "MASt3R (user's ONNX export)",
                _ => "?",
            };
            // dense models: how they were read (JSON written before the field: 4-px cells)
            let read = match kind {
                Some("disk" | "alike") => {
                    match ib.get("dense_stride").and_then(Value::as_u64).unwrap_or(4) {
                        1 => " (per pixel)".to_string(),
                        c => format!(" ({c}-px cells)"),
                    }
                }
                _ => String::new(),
            };
            let k = ib.get("k").and_then(Value::as_u64).unwrap_or(0);
            let label = format!("{vfm}{read} on {wfm}, K={k}");
            match mode.as_str() {
                "ImageOnly" => (label, "—".into(), "—".into()),
                "GeometryOnly" => ("—".into(), geo, "—".into()),
                m => (label, geo, fusion_name(m)),
            }
        }
    })
}

fn fusion_name(mode: &str) -> String {
    match mode {
        "NoisyAnd" => "Noisy-AND".into(),
        "NoisyOr" => "Noisy-OR".into(),
        "Concat" => "Concat.".into(),
        "Union" => "union".into(),
        "Visibility" => "visibility".into(),
        m => m.into(),
    }
}

/// The correspondence selection of a run (serde form of `fusion::Selection`).
fn selection_name(params: &Value) -> String {
    match params.pointer("/fusion/selection") {
        Some(Value::String(s)) if s == "MutualNn" => "mutual NN".into(),
        Some(Value::String(s)) if s == "RowNn" => "NN".into(),
        Some(Value::Object(o)) => match o.get("TopK").and_then(Value::as_u64) {
            Some(k) => format!("top-{k}"),
            None => "?".into(),
        },
        _ => "?".into(),
    }
}

/// The calibration of the branches a run uses, with its temperatures (image / geometric when
/// both are fused) and the Noisy-AND prior when it is not the default 1/(NM).
fn calibration_name(params: &Value) -> String {
    let cal = |ptr: &str| match params.pointer(ptr) {
        Some(Value::Object(o)) => {
            let (kind, body) = match (o.get("RowSoftmax"), o.get("DualSoftmax")) {
                (Some(b), _) => ("row", b),
                (None, Some(b)) => ("dual", b),
                _ => return ("?", "?".to_string()),
            };
            let tau = body
                .get("tau")
                .and_then(Value::as_f64)
                .map(|t| format!("{}", (t * 1e4).round() / 1e4))
                .unwrap_or_else(|| "?".into());
            (kind, tau)
        }
        _ => ("?", "?".to_string()),
    };
    let (ki, ti) = cal("/fusion/calibration_img");
    let (kg, tg) = cal("/fusion/calibration_geo");
    let image = params.get("image").is_some_and(|v| !v.is_null());
    let mode = params
        .pointer("/fusion/mode")
        .and_then(Value::as_str)
        .unwrap_or("?");
    let mut s = match (image, mode) {
        (false, _) | (true, "GeometryOnly") | (true, "Concat") => format!("{kg} τ {tg}"),
        (true, "ImageOnly") => format!("{ki} τ {ti}"),
        _ if ki == kg => format!("{ki} τ {ti}/{tg}"),
        _ => format!("{ki} τ {ti} / {kg} τ {tg}"),
    };
    if let Some(p) = params.pointer("/fusion/prior").and_then(Value::as_f64) {
        s.push_str(&format!(", π {p:e}"));
    }
    s
}

fn pct(v: &Value, k: &str) -> String {
    v.get(k)
        .and_then(Value::as_f64)
        .map(|x| format!("{:.1}", 100.0 * x))
        .unwrap_or_else(|| "–".into())
}

fn num(v: &Value, k: &str, scale: f64) -> String {
    v.get(k)
        .and_then(Value::as_f64)
        .filter(|x| x.is_finite())
        .map(|x| format!("{:.1}", scale * x))
        .unwrap_or_else(|| "inf".into())
}

pub fn run(a: TableArgs) -> Result<()> {
    outln!("| VFM (frames) | Geo. features | Fusion | selection | calibration τ (img/geo) | split | pairs | RR % | RA@5° | RA@10° | RA@45° | RRE mean° | RRE med.° | TA@5cm | TA@10cm | TA@25cm | RTE mean cm | RTE med. cm | s/pair |");
    outln!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for path in &a.files {
        let v: Value = crate::io::output::read_json(path, "`cgenreg bench --json` output")?;
        let params = field(path, &v, "/params")?;
        let (vfm, geo, fusion) = row_label(path, params)?;
        let mut selection = selection_name(params);
        if let Some(seed) = params.get("repose_seed").and_then(Value::as_u64) {
            selection.push_str(&format!(", source re-posed (seed {seed})"));
        }
        let calibration = calibration_name(params);
        let summaries = field(path, &v, "/summary")?.as_array().ok_or_else(|| {
            Error::format(
                path,
                "summary",
                "an array of per-split summaries",
                "not an array",
            )
        })?;
        for s in summaries {
            let split = s.get("split").and_then(Value::as_str).unwrap_or("?");
            if a.split
                .as_ref()
                .is_some_and(|w| !w.eq_ignore_ascii_case(split))
            {
                continue;
            }
            outln!(
                "| {vfm} | {geo} | {fusion} | {selection} | {calibration} | {split} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} |",
                s.get("n").and_then(Value::as_u64).unwrap_or(0),
                pct(s, "recall"),
                pct(s, "rot_acc_5"),
                pct(s, "rot_acc_10"),
                pct(s, "rot_acc_45"),
                num(s, "rre_mean", 1.0),
                num(s, "rre_median", 1.0),
                pct(s, "trans_acc_5cm"),
                pct(s, "trans_acc_10cm"),
                pct(s, "trans_acc_25cm"),
                num(s, "rte_mean", 100.0),
                num(s, "rte_median", 100.0),
                s.get("time_per_pair_s").and_then(Value::as_f64).unwrap_or(f64::NAN),
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::{FusionMode, Selection};
    use crate::pipeline::{ImageBranchParams, RegisterParams, WfmSpec};

    /// Labels come from the real serialised parameters (serde names are what the JSON holds).
    #[test]
    fn labels_from_serialised_params() {
        let p = Path::new("x.json");
        let geo = serde_json::to_value(RegisterParams::default()).unwrap();
        assert_eq!(
            row_label(p, &geo).unwrap(),
            ("—".into(), "FPFH".into(), "—".into())
        );
        let mut r = RegisterParams {
            image: Some(ImageBranchParams {
                backend: WfmSpec::Oracle,
                ..Default::default()
            }),
            ..Default::default()
        };
        r.fusion.mode = FusionMode::NoisyOr;
        r.fusion.selection = Selection::TopK(8000);
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(
            row_label(p, &v).unwrap(),
            (
                "XFeat on oracle RGB, K=4".into(),
                "FPFH".into(),
                "Noisy-OR".into()
            )
        );
        assert_eq!(selection_name(&v), "top-8000");
        let mut d = r.clone();
        d.image.as_mut().unwrap().vfm = crate::vfm::VfmSpec::Alike {
            model: "models/alike-t.onnx".into(),
        };
        let mut v2 = serde_json::to_value(&d).unwrap();
        assert_eq!(
            row_label(p, &v2).unwrap().0,
            "ALIKE (per pixel) on oracle RGB, K=4"
        );
        // written before the field existed: those rows read 4-px cells
        v2["image"].as_object_mut().unwrap().remove("dense_stride");
        assert_eq!(
            row_label(p, &v2).unwrap().0,
            "ALIKE (4-px cells) on oracle RGB, K=4"
        );
        assert_eq!(calibration_name(&v), "row τ 0.1/0.1");
        r.fusion.calibration_img = crate::fusion::Calibration::RowSoftmax { tau: 0.05 };
        r.fusion.prior = Some(1e-6);
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(calibration_name(&v), "row τ 0.05/0.1, π 1e-6");
        r.fusion.prior = None;
        r.fusion.mode = FusionMode::ImageOnly;
        r.fusion.selection = Selection::RowNn;
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(row_label(p, &v).unwrap().1, "—");
        assert_eq!(selection_name(&v), "NN");
        assert_eq!(calibration_name(&v), "row τ 0.05");
        assert_eq!(calibration_name(&geo), "row τ 0.1");
        r.image.as_mut().unwrap().backend = WfmSpec::Builtin;
        let v = serde_json::to_value(&r).unwrap();
        assert!(row_label(p, &v).unwrap().0.contains("not a WFM"));
        // Not a bench file: a clear error naming the field.
        let e = row_label(p, &serde_json::json!({}))
            .unwrap_err()
            .to_string();
        assert!(e.contains("geo_features"), "{e}");
    }
}
