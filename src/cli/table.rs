//! `cgenreg table`: several `bench --json` files as one table in the layout of the paper's
//! Table 4 (VFM | geometric features | fusion | rotation accuracy and error | translation
//! accuracy and error), one row per file and split. Rows are labelled from each file's own
//! parameters, so a row can never claim a backend it did not run.

use crate::error::Result;
use crate::fusion::FusionMode;
use crate::metrics::FieldSummary;
use crate::pipeline::RegisterParams;
use crate::report::bench_file::{field_summaries, read_bench_file};
use crate::report::labels;
use clap::Args;
#[cfg(test)]
use std::path::Path;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct TableArgs {
    /// `cgenreg bench --json` outputs, one row each (per split).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Only this split (e.g. 3DMatch).
    #[arg(long)]
    pub split: Option<String>,
}

/// The run's parameters, typed, from a bench output's JSON (what its rows are labelled from).
#[cfg(test)]
fn run_params(path: &Path, v: &serde_json::Value) -> Result<RegisterParams> {
    let params = v.get("params").cloned().unwrap_or(serde_json::Value::Null);
    crate::report::bench_file::params_from_json(path, &params)
}

/// (WFM + VFM, geometric features, fusion) of a run.
fn row_label(p: &RegisterParams) -> (String, String, String) {
    let geo = labels::geo(&p.geo_features);
    match &p.image {
        None => ("—".into(), geo, "—".into()),
        Some(ib) => {
            let label = format!(
                "{} on {}, K={}",
                labels::vfm(ib),
                labels::wfm(&ib.backend),
                ib.k
            );
            match p.fusion.mode {
                FusionMode::ImageOnly => (label, "—".into(), "—".into()),
                FusionMode::GeometryOnly => ("—".into(), geo, "—".into()),
                m => (label, geo, labels::fusion_mode(m).into()),
            }
        }
    }
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:.1}", 100.0 * x)
    } else {
        "–".into()
    }
}

fn num(x: f64, scale: f64) -> String {
    if x.is_finite() {
        format!("{:.1}", scale * x)
    } else {
        "inf".into()
    }
}

pub fn run(a: TableArgs) -> Result<()> {
    outln!("| VFM (frames) | Geo. features | Fusion | selection | calibration τ (img/geo) | split | pairs | RR % | RA@5° | RA@10° | RA@45° | RRE mean° | RRE med.° | TA@5cm | TA@10cm | TA@25cm | RTE mean cm | RTE med. cm | s/pair |");
    outln!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    // the paper-style rows of runs on the standard benchmarks, printed after the table
    let mut field = Vec::new();
    for path in &a.files {
        let f = read_bench_file(path)?;
        let p = f.register_params(path)?;
        let (vfm, geo, fusion) = row_label(&p);
        let mut selection = labels::selection(p.fusion.selection);
        // recorded beside the parameters by `bench --repose-seed`
        if let Some(seed) = f.repose_seed() {
            selection.push_str(&format!(", source re-posed (seed {seed})"));
        }
        if let Some(sc) = labels::scales(&p) {
            selection.push_str(&format!(", {sc}"));
        }
        let calibration = labels::calibration(&p);
        if f.pairs.iter().any(|r| r.scene.is_some() || r.rmse_counted) {
            let label = match (vfm.as_str(), fusion.as_str()) {
                ("—", _) => geo.clone(),
                (v, "—") => v.to_string(),
                (v, fu) => format!("{v} + {geo}, {fu}"),
            };
            field.extend(
                field_summaries(&f.pairs)
                    .into_iter()
                    .filter(|x| {
                        a.split
                            .as_ref()
                            .is_none_or(|w| w.eq_ignore_ascii_case(&x.benchmark))
                    })
                    .map(|x| (label.clone(), x)),
            );
        }
        for x in &f.summary {
            if a.split
                .as_ref()
                .is_some_and(|w| !w.eq_ignore_ascii_case(&x.split))
            {
                continue;
            }
            let s = &x.summary;
            outln!(
                "| {vfm} | {geo} | {fusion} | {selection} | {calibration} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} |",
                x.split,
                s.n,
                pct(s.recall),
                pct(s.rot_acc_5),
                pct(s.rot_acc_10),
                pct(s.rot_acc_45),
                num(s.rre_mean, 1.0),
                num(s.rre_median, 1.0),
                pct(s.trans_acc_5cm),
                pct(s.trans_acc_10cm),
                pct(s.trans_acc_25cm),
                num(s.rte_mean, 100.0),
                num(s.rte_median, 100.0),
                x.time_per_pair_s,
            );
        }
    }
    if !field.is_empty() {
        outln!();
        print_labelled_field_table(&field);
    }
    Ok(())
}

/// The paper-style rows of several runs, each labelled with its method (see
/// [`crate::cli::bench::print_field_table`] for the columns).
fn print_labelled_field_table(rows: &[(String, FieldSummary)]) {
    let also = rows.iter().find_map(|(_, r)| r.also.map(|(c, _)| c));
    let rmse = rows.iter().any(|(_, r)| r.rmse_recall.is_some());
    let crits: Vec<String> = {
        let mut v: Vec<String> = rows.iter().map(|(_, r)| r.criterion.label()).collect();
        v.dedup();
        v
    };
    outln!(
        "RR = registration recall at {}{}{}; RE / TE: mean and median over the registered pairs",
        crits.join(" / "),
        also.map_or(String::new(), |c| format!(
            "; RR {} at {}",
            c.short(),
            c.label()
        )),
        if rmse {
            "; RR RMSE = the official 3DMatch recall (RMSE < 0.2 m over gt.info, pairs of \
             non-consecutive fragments)"
        } else {
            ""
        }
    );
    outln!(
        "| method | benchmark | scene | pairs | RR % |{}{} RE mean ° | RE med ° | TE mean cm | TE med cm |",
        also.map_or(String::new(), |c| format!(" RR {} % |", c.short())),
        if rmse { " RR RMSE % (pairs) |" } else { "" }
    );
    outln!(
        "|---|---|---|---|---|{}{}---|---|---|---|",
        if also.is_some() { "---|" } else { "" },
        if rmse { "---|" } else { "" }
    );
    for (label, r) in rows {
        let also_cell = match (also, r.also) {
            (Some(_), Some((_, f))) => format!(" {} |", pct(f)),
            (Some(_), None) => " - |".into(),
            (None, _) => String::new(),
        };
        let rmse_cell = match (rmse, r.rmse_recall) {
            (true, Some(f)) => format!(" {} ({}) |", pct(f), r.rmse_pairs),
            (true, None) => " - |".into(),
            (false, _) => String::new(),
        };
        let fin = |v: f64, scale: f64| {
            if v.is_finite() {
                format!("{:.2}", scale * v)
            } else {
                "–".into()
            }
        };
        outln!(
            "| {label} | {} | {} | {} | {} |{also_cell}{rmse_cell} {} | {} | {} | {} |",
            r.benchmark,
            r.scene.as_deref().unwrap_or("all"),
            r.pairs,
            pct(r.rr),
            fin(r.re_mean_deg, 1.0),
            fin(r.re_median_deg, 1.0),
            fin(r.te_mean_m, 100.0),
            fin(r.te_median_m, 100.0),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::{FusionMode, Selection};
    use crate::pipeline::{ImageBranchParams, RegisterParams, WfmSpec};

    /// Labels come from the typed parameters, read back from their serialised form.
    #[test]
    fn labels_from_serialised_params() {
        let path = Path::new("x.json");
        let read = |p: &RegisterParams| {
            run_params(
                path,
                &serde_json::json!({ "params": serde_json::to_value(p).unwrap() }),
            )
            .unwrap()
        };
        let geo = read(&RegisterParams::default());
        assert_eq!(row_label(&geo), ("—".into(), "FPFH".into(), "—".into()));
        let mut r = RegisterParams {
            image: Some(ImageBranchParams {
                backend: WfmSpec::Oracle,
                ..Default::default()
            }),
            ..Default::default()
        };
        r.fusion.mode = FusionMode::NoisyOr;
        r.fusion.selection = Selection::TopK(8000);
        let v = read(&r);
        assert_eq!(
            row_label(&v),
            (
                "XFeat on oracle RGB, K=4".into(),
                "FPFH".into(),
                "Noisy-OR".into()
            )
        );
        assert_eq!(labels::selection(v.fusion.selection), "top-8000");
        let mut d = r.clone();
        d.image.as_mut().unwrap().vfm = crate::vfm::VfmSpec::Alike {
            model: "models/alike-t.onnx".into(),
        };
        assert_eq!(
            row_label(&read(&d)).0,
            "ALIKE (per pixel) on oracle RGB, K=4"
        );
        // written before the field existed: those rows read 4-px cells
        let mut old = serde_json::to_value(&d).unwrap();
        old["image"].as_object_mut().unwrap().remove("dense_stride");
        let old = run_params(path, &serde_json::json!({ "params": old })).unwrap();
        assert_eq!(row_label(&old).0, "ALIKE (4-px cells) on oracle RGB, K=4");
        assert_eq!(labels::calibration(&v), "row τ 0.1/0.1");
        r.fusion.calibration_img = crate::fusion::Calibration::RowSoftmax { tau: 0.05 };
        r.fusion.prior = Some(1e-6);
        assert_eq!(labels::calibration(&read(&r)), "row τ 0.05/0.1, π 1e-6");
        r.fusion.prior = None;
        r.fusion.mode = FusionMode::ImageOnly;
        r.fusion.selection = Selection::RowNn;
        let v = read(&r);
        assert_eq!(row_label(&v).1, "—");
        assert_eq!(labels::selection(v.fusion.selection), "NN");
        assert_eq!(labels::calibration(&v), "row τ 0.05");
        assert_eq!(labels::calibration(&geo), "row τ 0.1");
        r.image.as_mut().unwrap().backend = WfmSpec::Builtin;
        assert!(row_label(&read(&r)).0.contains("not a WFM"));
        // Not a bench file: a clear error naming the field.
        let e = run_params(path, &serde_json::json!({}))
            .unwrap_err()
            .to_string();
        assert!(e.contains("params"), "{e}");
        let e = run_params(path, &serde_json::json!({ "params": { "voxel": "x" } }))
            .unwrap_err()
            .to_string();
        assert!(e.contains("params"), "{e}");
    }
}
