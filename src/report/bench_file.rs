//! A `cgenreg bench --json` output: its writer ([`bench_json`], for `bench` and `merge`) and
//! its typed reader ([`read_bench_file`], for `table`, `diff` and the Compare tab): the run file (header and one record per
//! pair), the parameters as recorded, one row per pair ([`PairRow`]) and one summary per split
//! ([`SplitSummary`]).

use crate::error::{Error, Result};
use crate::metrics::{FieldPair, FieldSummary, PairMetrics, SuccessCriterion, Summary};
use crate::pipeline::params::RegisterParams;
use crate::pipeline::shard::{PairRecord, RunFile, RunHeader};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

pub use super::compare::PairRow;

#[derive(Serialize)]
struct BenchJson<'a> {
    manifest: String,
    params: &'a serde_json::Value,
    run: &'a RunHeader,
    pairs: Vec<PairRow>,
    summary: Vec<SplitSummary>,
    /// The paper-style rows: per benchmark (split) and scene, and pooled per benchmark.
    field: Vec<FieldSummary>,
    records: &'a [PairRecord],
}

/// One split's summary in a bench output. `summary.recall` counts successes under
/// `criterion`. (Outputs written before this type wrote `recall` twice, with one value: a JSON
/// reader keeps one of them.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SplitSummary {
    pub split: String,
    /// What the recall counts (the pairs' criterion; 3DMatch's for rows that do not name one,
    /// and in outputs written before it was named).
    #[serde(default)]
    pub criterion: SuccessCriterion,
    /// The fraction of pairs that succeed under the run's second criterion, when it has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub also: Option<(SuccessCriterion, f64)>,
    #[serde(flatten)]
    pub summary: Summary,
    pub time_per_pair_s: f64,
    /// Pairs that ran with an error: failures in the recall and accuracies, left out of the
    /// error means and medians (which are over the pairs with a pose). 0 in outputs written
    /// before it was counted.
    #[serde(default)]
    pub errors: usize,
}

/// The rows of a run file's records, in order.
pub fn rows_of(f: &RunFile) -> Result<Vec<PairRow>> {
    f.records
        .iter()
        .map(|r| {
            serde_json::from_value::<PairRow>(r.result.clone())
                .map_err(|e| Error::Invalid(format!("pair {}: not a bench result: {e}", r.id)))
        })
        .collect()
}

/// Bench output bytes for a run file (what `bench` and `merge` write).
pub fn bench_json(f: &RunFile) -> Result<Vec<u8>> {
    let rows = rows_of(f)?;
    let summary = summarise(&rows);
    let field = field_summaries(&rows);
    let out = BenchJson {
        manifest: f.run.identity.manifest.clone(),
        params: &f.run.identity.params,
        run: &f.run,
        pairs: rows,
        summary,
        field,
        records: &f.records,
    };
    serde_json::to_vec_pretty(&out).map_err(|e| Error::Encode(format!("serialising results: {e}")))
}

/// Per-split summaries (splits sorted by name). A pair that ran with an error counts as a
/// failure with infinite error, so recall and accuracies stay honest; the error means and
/// medians are over the pairs with a pose ([`Summary::from_pairs`]).
pub fn summarise(rows: &[PairRow]) -> Vec<SplitSummary> {
    let mut splits: Vec<String> = rows.iter().map(|r| r.split.clone()).collect();
    splits.sort();
    splits.dedup();
    splits
        .iter()
        .map(|split| {
            let sel: Vec<&PairRow> = rows.iter().filter(|r| &r.split == split).collect();
            let pm: Vec<PairMetrics> = sel
                .iter()
                .map(|r| PairMetrics {
                    rre_deg: r.rre_deg.unwrap_or(f64::INFINITY),
                    rte_m: r.rte_m.unwrap_or(f64::INFINITY),
                    inlier_ratio: r.inlier_ratio.unwrap_or(0.0),
                    success: r.success.unwrap_or(false),
                    criterion: r.criterion.unwrap_or_default(),
                    also: r.also,
                })
                .collect();
            let s = Summary::from_pairs(&pm);
            let tpp = sel.iter().map(|r| r.time_s).sum::<f64>() / sel.len().max(1) as f64;
            let criterion = sel
                .iter()
                .find_map(|r| r.criterion)
                .unwrap_or(SuccessCriterion::THREEDMATCH);
            // a pair that failed to run fails the second criterion too
            let also = sel.iter().find_map(|r| r.also).map(|j| {
                let n = sel
                    .iter()
                    .filter(|r| r.also.is_some_and(|a| a.success))
                    .count();
                (j.criterion, n as f64 / sel.len().max(1) as f64)
            });
            SplitSummary {
                split: split.clone(),
                criterion,
                also,
                summary: s,
                time_per_pair_s: tpp,
                errors: sel.iter().filter(|r| r.rre_deg.is_none()).count(),
            }
        })
        .collect()
}

/// The paper-style rows of a run (SC2-PCR's and GeoTransformer's tables): for each benchmark
/// (split, sorted by name), one row per scene when the pairs name scenes, then the benchmark
/// pooled over its pairs. A pair that ran with an error is a failure everywhere.
pub fn field_summaries(rows: &[PairRow]) -> Vec<FieldSummary> {
    let mut splits: Vec<&str> = rows.iter().map(|r| r.split.as_str()).collect();
    splits.sort_unstable();
    splits.dedup();
    let mut out = Vec::new();
    for split in splits {
        let sel: Vec<&PairRow> = rows.iter().filter(|r| r.split == split).collect();
        let criterion = sel
            .iter()
            .find_map(|r| r.criterion)
            .unwrap_or(SuccessCriterion::THREEDMATCH);
        let also = sel.iter().find_map(|r| r.also.map(|j| j.criterion));
        let pair = |r: &&PairRow| FieldPair {
            rre_deg: r.rre_deg.unwrap_or(f64::INFINITY),
            rte_m: r.rte_m.unwrap_or(f64::INFINITY),
            success: r.success.unwrap_or(false),
            also_success: also.map(|_| r.also.is_some_and(|j| j.success)),
            rmse_m: r.rmse_counted.then(|| r.rmse_m.unwrap_or(f64::INFINITY)),
        };
        let mut scenes: Vec<&str> = sel.iter().filter_map(|r| r.scene.as_deref()).collect();
        scenes.sort_unstable();
        scenes.dedup();
        for scene in &scenes {
            let pairs: Vec<FieldPair> = sel
                .iter()
                .filter(|r| r.scene.as_deref() == Some(scene))
                .map(pair)
                .collect();
            out.push(FieldSummary::from_pairs(
                split,
                Some(scene),
                criterion,
                also,
                &pairs,
            ));
        }
        let all: Vec<FieldPair> = sel.iter().map(pair).collect();
        out.push(FieldSummary::from_pairs(split, None, criterion, also, &all));
    }
    out
}

/// A bench output as written: what `table`, `diff` and the Compare tab read (the last two
/// through [`super::compare::load_bench_run`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BenchFile {
    /// The manifest, as given to `bench` (relative to where it ran).
    pub manifest: Option<String>,
    /// The registration parameters as recorded (with `repose_seed` beside them when the run
    /// re-posed its sources); [`BenchFile::register_params`] types them.
    pub params: Value,
    /// The run file's header (None in outputs written before runs were resumable).
    pub run: Option<RunHeader>,
    pub pairs: Vec<PairRow>,
    pub summary: Vec<SplitSummary>,
    /// Empty in outputs written before runs were resumable.
    pub records: Vec<PairRecord>,
}

impl BenchFile {
    /// The run's parameters, typed (what its rows are labelled from); `path` names the file
    /// in the error.
    pub fn register_params(&self, path: &Path) -> Result<RegisterParams> {
        params_from_json(path, &self.params)
    }

    /// The seed of `bench --repose-seed`, recorded beside the parameters.
    pub fn repose_seed(&self) -> Option<u64> {
        self.params.get("repose_seed").and_then(Value::as_u64)
    }
}

/// Recorded registration parameters, typed; `path` names the file in the error.
pub fn params_from_json(path: &Path, params: &Value) -> Result<RegisterParams> {
    let expected = "the registration parameters of a `cgenreg bench --json` output";
    if params.is_null() {
        return Err(Error::format(path, "params", expected, "missing"));
    }
    serde_json::from_value(params.clone())
        .map_err(|e| Error::format(path, "params", expected, e.to_string()))
}

/// Reads a `cgenreg bench --json` (or `cgenreg merge`) output, typed; errors name the file and
/// the field. Bounded, regular files only (a /dev/zero link is refused before any read).
pub fn read_bench_file(path: &Path) -> Result<BenchFile> {
    // through a JSON value: older outputs hold `recall` twice in each summary, which a value
    // keeps once (a typed reader would call it a duplicate field)
    let v: Value = crate::io::output::read_json(path, "`cgenreg bench --json` output")?;
    let missing = |name: &str| {
        Error::format(
            path,
            name,
            "a field of `cgenreg bench --json` output",
            "missing",
        )
    };
    let mut run: Option<RunHeader> = field(path, &v, "run")?;
    let mut records: Vec<PairRecord> = field(path, &v, "records")?.unwrap_or_default();
    // A file with a run header is a run file: its header and records are checked against each
    // other as `merge` and `status` check them (read_run_file), so no reader trusts a corrupt one.
    if let Some(header) = run.take() {
        let f = RunFile {
            run: header,
            records,
        };
        f.check(path)?;
        (run, records) = (Some(f.run), f.records);
    }
    Ok(BenchFile {
        manifest: field(path, &v, "manifest")?,
        params: v.get("params").cloned().ok_or_else(|| missing("params"))?,
        run,
        pairs: field(path, &v, "pairs")?.ok_or_else(|| missing("pairs"))?,
        summary: field(path, &v, "summary")?.ok_or_else(|| missing("summary"))?,
        records,
    })
}

/// The top-level field `name` of `v`, typed (None when absent or null).
fn field<T: serde::de::DeserializeOwned>(path: &Path, v: &Value, name: &str) -> Result<Option<T>> {
    match v.get(name) {
        None | Some(Value::Null) => Ok(None),
        Some(x) => serde_json::from_value(x.clone()).map(Some).map_err(|e| {
            Error::format(
                path,
                name,
                "the field as `cgenreg bench --json` writes it",
                e.to_string(),
            )
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::shard::{RunIdentity, Shard, DONE};

    fn row(id: &str, rre: Option<f64>, success: bool) -> PairRow {
        PairRow {
            id: id.into(),
            split: "3DMatch".into(),
            rre_deg: rre,
            rte_m: rre.map(|r| r / 100.0),
            inlier_ratio: Some(0.2),
            success: Some(success),
            time_s: 1.5,
            criterion: Some(SuccessCriterion::THREEDMATCH),
            ..Default::default()
        }
    }

    fn run_file(rows: &[PairRow]) -> RunFile {
        let selected: Vec<String> = rows.iter().map(|r| r.id.clone()).collect();
        RunFile {
            run: RunHeader {
                identity: RunIdentity {
                    command: "bench".into(),
                    manifest: "m.toml".into(),
                    manifest_blake3: String::new(),
                    split: None,
                    limit: None,
                    params: serde_json::to_value(RegisterParams::default()).unwrap(),
                    shard_count: 1,
                    code_version: "cgenreg test".into(),
                    binary_blake3: String::new(),
                    selected,
                },
                shard: Shard::default(),
                merged_from: Vec::new(),
                complete: true,
                in_flight: None,
                host: "h".into(),
                updated_unix: 0,
                machine: None,
                commit: None,
                shard_runs: Vec::new(),
            },
            records: rows
                .iter()
                .map(|r| PairRecord {
                    id: r.id.clone(),
                    status: DONE.into(),
                    error: None,
                    time_s: r.time_s,
                    stages: Vec::new(),
                    result: serde_json::to_value(r).unwrap(),
                })
                .collect(),
        }
    }

    /// What `bench` writes, `table` reads back: the same rows and summaries, each summary
    /// with one `recall`.
    #[test]
    fn the_writer_and_the_reader_agree() {
        let rows = [row("a", Some(2.0), true), row("b", None, false)];
        let f = run_file(&rows);
        let bytes = bench_json(&f).unwrap();
        let text = String::from_utf8(bytes.clone()).unwrap();
        assert_eq!(text.matches("\"recall\"").count(), 1, "{text}");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.json");
        std::fs::write(&path, &bytes).unwrap();
        let back = read_bench_file(&path).unwrap();
        assert_eq!(back.pairs, rows.to_vec());
        assert_eq!(back.summary, summarise(&rows));
        assert_eq!(back.summary[0].summary.recall, 0.5);
        assert_eq!(back.summary[0].errors, 1);
        assert_eq!(back.run.as_ref(), Some(&f.run));
        assert_eq!(back.records, f.records);
        assert_eq!(
            back.register_params(&path).unwrap(),
            RegisterParams::default()
        );
        assert_eq!(back.repose_seed(), None);
    }

    /// A header that disagrees with its records (a pair the run never selected, a pair twice)
    /// is refused by the typed reader as `merge` and `status` refuse it.
    #[test]
    fn a_run_header_is_checked_against_its_records() {
        let rows = [row("a", Some(2.0), true), row("b", None, false)];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.json");
        // the reader's error for the run file whose record `i` has the id `id`
        let refused = |i: usize, id: &str| {
            let mut f = run_file(&rows);
            f.records[i].id = id.into();
            std::fs::write(&path, bench_json(&f).unwrap()).unwrap();
            read_bench_file(&path).unwrap_err().to_string()
        };
        let e = refused(1, "a");
        assert!(
            e.contains(": records[1].id: expected each pair once"),
            "{e}"
        );
        let e = refused(0, "elsewhere");
        assert!(
            e.contains(": records[0].id: expected a pair of run.identity.selected"),
            "{e}"
        );
        // and the params of an output without them name the field
        let mut v: Value = serde_json::from_slice(&bench_json(&run_file(&rows)).unwrap()).unwrap();
        v["params"] = Value::Null;
        std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
        let back = read_bench_file(&path).unwrap();
        let e = back.register_params(&path).unwrap_err().to_string();
        assert!(e.contains(": params: ") && e.ends_with("missing"), "{e}");
    }

    /// Outputs written by earlier versions: `recall` twice, no criterion, error count, header
    /// or records, a mean with no finite value written as null.
    #[test]
    fn older_outputs_are_read() {
        let params = serde_json::to_value(RegisterParams::default()).unwrap();
        let text = format!(
            r#"{{"manifest": "m.toml", "params": {params}, "pairs": [],
              "summary": [{{"split": "3DMatch", "recall": 0.0, "n": 1, "recall": 0.0,
                "rot_acc_5": 0.0, "rot_acc_10": 0.0, "rot_acc_45": 0.0, "rre_mean": null,
                "rre_median": null, "trans_acc_5cm": 0.0, "trans_acc_10cm": 0.0,
                "trans_acc_25cm": 0.0, "rte_mean": null, "rte_median": null, "ir_mean": 0.0,
                "time_per_pair_s": 2.0}}]}}"#
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.json");
        std::fs::write(&path, text).unwrap();
        let f = read_bench_file(&path).unwrap();
        let s = &f.summary[0];
        assert_eq!(s.criterion, SuccessCriterion::THREEDMATCH);
        assert_eq!((s.summary.n, s.errors, s.also), (1, 0, None));
        assert!(s.summary.rre_mean.is_nan() && s.summary.rte_median.is_nan());
        assert!(f.run.is_none() && f.records.is_empty());
        // a summary without its split is an error naming the file and the field
        std::fs::write(
            &path,
            r#"{"params": {}, "pairs": [], "summary": [{"n": 1}]}"#,
        )
        .unwrap();
        let e = read_bench_file(&path).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: summary: ", path.display())),
            "{e}"
        );
        assert!(e.contains("split"), "{e}");
        std::fs::write(&path, r#"{"params": {}, "summary": []}"#).unwrap();
        let e = read_bench_file(&path).unwrap_err().to_string();
        assert!(e.contains(": pairs: ") && e.contains("missing"), "{e}");
    }
}
