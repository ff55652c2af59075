//! Two runs over the same pairs, compared: pairs matched by id, successes that flipped,
//! ΔRRE / ΔRTE (B minus A), the four success quadrants, and what differs between the runs'
//! parameters. `cgenreg diff` prints it; the inspector's Compare tab draws it. The comparison
//! itself is pure ([`compare`]); [`load_bench_run`] reads a `cgenreg bench --json` output.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

/// One pair's row of a bench run (the `pairs` array of `cgenreg bench --json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairRow {
    pub id: String,
    pub split: String,
    pub source: String,
    pub target: String,
    pub rre_deg: Option<f64>,
    pub rte_m: Option<f64>,
    pub inlier_ratio: Option<f64>,
    /// RRE ≤ 15° and RTE ≤ 0.30 m; a pair that failed to run is `Some(false)`.
    pub success: Option<bool>,
    pub time_s: f64,
    pub error: Option<String>,
}

impl PairRow {
    /// The row of a pair that could not be registered.
    pub fn failed(spec_id: &str, split: &str, why: &str, time_s: f64) -> PairRow {
        PairRow {
            id: spec_id.to_string(),
            split: split.to_string(),
            source: String::new(),
            target: String::new(),
            rre_deg: None,
            rte_m: None,
            inlier_ratio: None,
            success: Some(false),
            time_s,
            error: Some(why.to_string()),
        }
    }
}

/// A bench run as the comparison needs it: a label, its parameters and identity, its rows.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRun {
    /// The file it came from (or another name for the run).
    pub label: String,
    /// The run's parameters (`params`).
    pub params: Value,
    /// The run identity without parameters and pair list (manifest, split, limit, code).
    pub identity: Value,
    pub pairs: Vec<PairRow>,
}

/// Reads a `cgenreg bench --json` (or `cgenreg merge`) output.
pub fn load_bench_run(path: &Path) -> Result<BenchRun> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let v: Value = serde_json::from_slice(&bytes).map_err(|e| {
        Error::format(
            path,
            "(root)",
            "a cgenreg bench --json output",
            e.to_string(),
        )
    })?;
    bench_run_from_json(&path.display().to_string(), &v).map_err(|(field, why)| {
        Error::format(
            path,
            &field,
            "a cgenreg bench --json output (pairs, params, run.identity)",
            why,
        )
    })
}

/// [`load_bench_run`] on parsed JSON; errors name the field.
pub fn bench_run_from_json(
    label: &str,
    v: &Value,
) -> std::result::Result<BenchRun, (String, String)> {
    let pairs = v
        .get("pairs")
        .ok_or_else(|| ("pairs".to_string(), "missing".to_string()))?;
    let pairs: Vec<PairRow> =
        serde_json::from_value(pairs.clone()).map_err(|e| ("pairs".to_string(), e.to_string()))?;
    let params = v
        .get("params")
        .cloned()
        .ok_or_else(|| ("params".to_string(), "missing".to_string()))?;
    let mut identity = v.pointer("/run/identity").cloned().unwrap_or(Value::Null);
    if let Value::Object(m) = &mut identity {
        // compared on their own: the parameters (above) and the pairs (matched by id)
        for k in ["params", "selected", "shard_count"] {
            m.remove(k);
        }
    }
    Ok(BenchRun {
        label: label.to_string(),
        params,
        identity,
        pairs,
    })
}

/// How a pair's success changed from run A to run B.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Flip {
    BothSuccess,
    BothFailure,
    /// Failure in A, success in B.
    Gained,
    /// Success in A, failure in B.
    Lost,
    /// Success unknown in one run (no ground truth).
    Unknown,
}

impl Flip {
    pub fn label(self) -> &'static str {
        match self {
            Flip::BothSuccess => "both succeed",
            Flip::BothFailure => "both fail",
            Flip::Gained => "gained (B only)",
            Flip::Lost => "lost (A only)",
            Flip::Unknown => "unknown",
        }
    }
}

/// One pair in both runs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PairDiff {
    pub id: String,
    pub split: String,
    pub a: PairRow,
    pub b: PairRow,
    pub flip: Flip,
    /// RRE of B minus RRE of A (degrees); None when either is missing.
    pub d_rre_deg: Option<f64>,
    /// RTE of B minus RTE of A (metres).
    pub d_rte_m: Option<f64>,
}

/// Counts of the four success quadrants over the pairs in both runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Quadrants {
    pub both_success: usize,
    pub only_a: usize,
    pub only_b: usize,
    pub both_failure: usize,
    pub unknown: usize,
}

/// Two runs compared (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Comparison {
    pub a: String,
    pub b: String,
    /// Pairs in both runs, in A's order.
    pub pairs: Vec<PairDiff>,
    /// Pair ids in one run only.
    pub only_in_a: Vec<String>,
    pub only_in_b: Vec<String>,
    pub quadrants: Quadrants,
    /// "fusion.mode: \"NoisyAnd\" in A, \"GeometryOnly\" in B", one line per parameter.
    pub param_differences: Vec<String>,
    /// Other differences of the run identities (manifest, split, limit, code version).
    pub run_differences: Vec<String>,
    /// Recall of each run over the pairs in both (success / pairs with known success).
    pub recall_a: Option<f64>,
    pub recall_b: Option<f64>,
    /// Median ΔRRE / ΔRTE over the pairs with both values.
    pub median_d_rre_deg: Option<f64>,
    pub median_d_rte_m: Option<f64>,
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    })
}

/// Compares run `b` with run `a` (pure).
pub fn compare(a: &BenchRun, b: &BenchRun) -> Comparison {
    let by_id: std::collections::HashMap<&str, &PairRow> =
        b.pairs.iter().map(|p| (p.id.as_str(), p)).collect();
    let in_a: std::collections::HashSet<&str> = a.pairs.iter().map(|p| p.id.as_str()).collect();
    let mut q = Quadrants::default();
    let mut pairs = Vec::new();
    let mut only_in_a = Vec::new();
    for pa in &a.pairs {
        let Some(pb) = by_id.get(pa.id.as_str()) else {
            only_in_a.push(pa.id.clone());
            continue;
        };
        let flip = match (pa.success, pb.success) {
            (Some(true), Some(true)) => Flip::BothSuccess,
            (Some(false), Some(false)) => Flip::BothFailure,
            (Some(false), Some(true)) => Flip::Gained,
            (Some(true), Some(false)) => Flip::Lost,
            _ => Flip::Unknown,
        };
        match flip {
            Flip::BothSuccess => q.both_success += 1,
            Flip::BothFailure => q.both_failure += 1,
            Flip::Gained => q.only_b += 1,
            Flip::Lost => q.only_a += 1,
            Flip::Unknown => q.unknown += 1,
        }
        let d = |x: Option<f64>, y: Option<f64>| Some(y? - x?);
        pairs.push(PairDiff {
            id: pa.id.clone(),
            split: pa.split.clone(),
            a: pa.clone(),
            b: (*pb).clone(),
            flip,
            d_rre_deg: d(pa.rre_deg, pb.rre_deg),
            d_rte_m: d(pa.rte_m, pb.rte_m),
        });
    }
    let only_in_b = b
        .pairs
        .iter()
        .filter(|p| !in_a.contains(p.id.as_str()))
        .map(|p| p.id.clone())
        .collect();
    let known = pairs.len() - q.unknown;
    let recall = |n: usize| (known > 0).then(|| n as f64 / known as f64);
    let mut param_differences = Vec::new();
    let ab = ("in A", "in B");
    json_diff("", &a.params, &b.params, ab, &mut param_differences);
    let mut run_differences = Vec::new();
    json_diff("", &a.identity, &b.identity, ab, &mut run_differences);
    Comparison {
        a: a.label.clone(),
        b: b.label.clone(),
        median_d_rre_deg: median(pairs.iter().filter_map(|p| p.d_rre_deg).collect()),
        median_d_rte_m: median(pairs.iter().filter_map(|p| p.d_rte_m).collect()),
        recall_a: recall(q.both_success + q.only_a),
        recall_b: recall(q.both_success + q.only_b),
        pairs,
        only_in_a,
        only_in_b,
        quadrants: q,
        param_differences,
        run_differences,
    }
}

/// Leaf-by-leaf differences of two JSON values, `labels` naming the two sides:
/// "params.voxel: 0.05 here, 0.1 there". Long arrays (the selected pairs) are summarised.
pub fn json_diff(path: &str, a: &Value, b: &Value, labels: (&str, &str), out: &mut Vec<String>) {
    let (la, lb) = labels;
    if a == b {
        return;
    }
    let name = if path.is_empty() { "(root)" } else { path };
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                json_diff(
                    &p,
                    x.get(k).unwrap_or(&Value::Null),
                    y.get(k).unwrap_or(&Value::Null),
                    labels,
                    out,
                );
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() > 8 || y.len() > 8 => {
            let first = x.iter().zip(y).position(|(p, q)| p != q);
            out.push(format!(
                "{name}: {} entries {la}, {} {lb}{}",
                x.len(),
                y.len(),
                first
                    .map(|i| format!(", first difference at entry {i}"))
                    .unwrap_or_default()
            ));
        }
        _ => out.push(format!("{name}: {a} {la}, {b} {lb}")),
    }
}

/// The comparison as a plain-text table: one row per pair (flipped pairs first, then by
/// |ΔRRE|), then the quadrants and the differences of the runs.
pub fn table(c: &Comparison) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "A: {}\nB: {}", c.a, c.b);
    if c.param_differences.is_empty() {
        let _ = writeln!(s, "parameters: identical");
    } else {
        let _ = writeln!(s, "parameters that differ:");
        for d in &c.param_differences {
            let _ = writeln!(s, "  {d}");
        }
    }
    for d in &c.run_differences {
        let _ = writeln!(s, "  run: {d}");
    }
    let f = |v: Option<f64>, scale: f64, p: usize| {
        v.map(|x| format!("{:.*}", p, x * scale))
            .unwrap_or_else(|| "–".into())
    };
    let w = c.pairs.iter().map(|p| p.id.len()).max().unwrap_or(4).max(4);
    let _ = writeln!(
        s,
        "\n{:<w$}  {:<16} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "pair", "flip", "RRE A°", "RRE B°", "ΔRRE°", "RTE A cm", "RTE B cm", "ΔRTE cm"
    );
    let mut order: Vec<&PairDiff> = c.pairs.iter().collect();
    let flipped = |p: &PairDiff| !matches!(p.flip, Flip::Gained | Flip::Lost);
    order.sort_by(|x, y| {
        flipped(x).cmp(&flipped(y)).then(
            y.d_rre_deg
                .map(f64::abs)
                .unwrap_or(-1.0)
                .total_cmp(&x.d_rre_deg.map(f64::abs).unwrap_or(-1.0)),
        )
    });
    for p in order {
        let _ = writeln!(
            s,
            "{:<w$}  {:<16} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
            p.id,
            p.flip.label(),
            f(p.a.rre_deg, 1.0, 2),
            f(p.b.rre_deg, 1.0, 2),
            f(p.d_rre_deg, 1.0, 2),
            f(p.a.rte_m, 100.0, 1),
            f(p.b.rte_m, 100.0, 1),
            f(p.d_rte_m, 100.0, 1),
        );
    }
    let q = &c.quadrants;
    let _ = writeln!(
        s,
        "\n{} pairs in both: {} both succeed, {} only A, {} only B, {} both fail{}",
        c.pairs.len(),
        q.both_success,
        q.only_a,
        q.only_b,
        q.both_failure,
        if q.unknown > 0 {
            format!(", {} without ground truth", q.unknown)
        } else {
            String::new()
        }
    );
    let _ = writeln!(
        s,
        "recall A {} · recall B {} · median ΔRRE {}° · median ΔRTE {} cm",
        f(c.recall_a, 100.0, 1) + " %",
        f(c.recall_b, 100.0, 1) + " %",
        f(c.median_d_rre_deg, 1.0, 3),
        f(c.median_d_rte_m, 100.0, 2)
    );
    if !c.only_in_a.is_empty() || !c.only_in_b.is_empty() {
        let _ = writeln!(
            s,
            "{} pairs only in A, {} only in B (not compared)",
            c.only_in_a.len(),
            c.only_in_b.len()
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn row(id: &str, rre: Option<f64>, rte: Option<f64>) -> PairRow {
        PairRow {
            id: id.into(),
            split: "3DMatch".into(),
            source: String::new(),
            target: String::new(),
            rre_deg: rre,
            rte_m: rte,
            inlier_ratio: None,
            success: match (rre, rte) {
                (Some(r), Some(t)) => Some(r <= 15.0 && t <= 0.3),
                _ => None,
            },
            time_s: 1.0,
            error: None,
        }
    }

    fn run(label: &str, mode: &str, pairs: Vec<PairRow>) -> BenchRun {
        BenchRun {
            label: label.into(),
            params: json!({"voxel": 0.05, "fusion": {"mode": mode}}),
            identity: json!({"manifest": "m.toml", "split": null}),
            pairs,
        }
    }

    #[test]
    fn flips_deltas_quadrants_and_parameter_differences() {
        let a = run(
            "a.json",
            "NoisyAnd",
            vec![
                row("p1", Some(2.0), Some(0.05)),
                row("p2", Some(40.0), Some(0.5)),
                row("p3", Some(3.0), Some(0.1)),
                row("p4", Some(90.0), Some(2.0)),
                row("only-a", Some(1.0), Some(0.01)),
                row("nogt", None, None),
            ],
        );
        let mut failed = PairRow::failed("p3", "3DMatch", "no overlap", 0.1);
        failed.split = "3DMatch".into();
        let b = run(
            "b.json",
            "GeometryOnly",
            vec![
                row("p2", Some(5.0), Some(0.1)),
                row("p1", Some(2.5), Some(0.04)),
                failed,
                row("p4", Some(80.0), Some(1.0)),
                row("nogt", None, None),
                row("only-b", Some(1.0), Some(0.01)),
            ],
        );
        let c = compare(&a, &b);
        let ids: Vec<&str> = c.pairs.iter().map(|p| p.id.as_str()).collect();
        assert_eq!(ids, ["p1", "p2", "p3", "p4", "nogt"], "A's order");
        assert_eq!(c.only_in_a, ["only-a"]);
        assert_eq!(c.only_in_b, ["only-b"]);
        let flip = |id: &str| c.pairs.iter().find(|p| p.id == id).unwrap().flip;
        assert_eq!(flip("p1"), Flip::BothSuccess);
        assert_eq!(flip("p2"), Flip::Gained);
        assert_eq!(
            flip("p3"),
            Flip::Lost,
            "a pair that failed to run is a failure"
        );
        assert_eq!(flip("p4"), Flip::BothFailure);
        assert_eq!(flip("nogt"), Flip::Unknown);
        assert_eq!(
            c.quadrants,
            Quadrants {
                both_success: 1,
                only_a: 1,
                only_b: 1,
                both_failure: 1,
                unknown: 1
            }
        );
        let p1 = &c.pairs[0];
        assert!((p1.d_rre_deg.unwrap() - 0.5).abs() < 1e-12);
        assert!((p1.d_rte_m.unwrap() + 0.01).abs() < 1e-12);
        assert_eq!(c.pairs[2].d_rre_deg, None);
        assert_eq!(c.recall_a, Some(0.5));
        assert_eq!(c.recall_b, Some(0.5));
        // ΔRRE of p1, p2, p4: 0.5, -35, -10 -> median -10
        assert_eq!(c.median_d_rre_deg, Some(-10.0));
        assert_eq!(
            c.param_differences,
            ["fusion.mode: \"NoisyAnd\" in A, \"GeometryOnly\" in B"]
        );
        assert!(c.run_differences.is_empty());
        let t = table(&c);
        assert!(
            t.contains("gained (B only)") && t.contains("lost (A only)"),
            "{t}"
        );
        assert!(t.contains("1 only A, 1 only B"), "{t}");
        // flipped pairs come first in the table
        let first = t
            .lines()
            .skip_while(|l| !l.starts_with("pair "))
            .nth(1)
            .unwrap();
        assert!(first.starts_with("p2") || first.starts_with("p3"), "{t}");
    }

    #[test]
    fn identical_runs_and_bad_files() {
        let a = run("a", "NoisyAnd", vec![row("p1", Some(2.0), Some(0.05))]);
        let c = compare(&a, &a);
        assert!(c.param_differences.is_empty() && c.run_differences.is_empty());
        assert_eq!(c.pairs[0].d_rre_deg, Some(0.0));
        let e = bench_run_from_json("x", &json!({"params": {}})).unwrap_err();
        assert_eq!(e.0, "pairs");
        let e = bench_run_from_json("x", &json!({"pairs": [{"id": 3}], "params": {}})).unwrap_err();
        assert_eq!(e.0, "pairs");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.json");
        std::fs::write(&p, b"{not json").unwrap();
        let e = load_bench_run(&p).unwrap_err().to_string();
        assert!(e.contains("bad.json"), "{e}");
    }
}
