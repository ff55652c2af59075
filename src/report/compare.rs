//! Two runs over the same pairs, compared: pairs matched by id, successes that flipped,
//! ΔRRE / ΔRTE (B minus A), the four success quadrants, and what differs between the runs'
//! parameters. `cgenreg diff` prints it; the inspector's Compare tab draws it. The comparison
//! itself is pure ([`compare`]); [`load_bench_run`] reads a `cgenreg bench --json` output.

use crate::pipeline::params::RegisterParams;
use crate::Result;
use serde::{Deserialize, Serialize};
use serde_json::Value;

pub use crate::io::json_diff::json_diff;
use crate::io::json_diff::json_diff_settings;
use std::path::Path;

/// One pair's row of a bench run (the `pairs` array of `cgenreg bench --json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PairRow {
    pub id: String,
    pub split: String,
    pub source: String,
    pub target: String,
    pub rre_deg: Option<f64>,
    pub rte_m: Option<f64>,
    pub inlier_ratio: Option<f64>,
    /// Under `criterion`; a pair that failed to run is `Some(false)`.
    pub success: Option<bool>,
    pub time_s: f64,
    pub error: Option<String>,
    /// The criterion `success` was judged by (None in rows written before it was named, or
    /// of a pair that failed to run: 3DMatch's 15° / 0.30 m for the former).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub criterion: Option<crate::metrics::SuccessCriterion>,
    /// The run's second criterion, when it has one (the outdoor preset: SC2-PCR's 5° / 0.6 m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub also: Option<crate::metrics::Judged>,
    /// The ground truth's translation norm (m): how far apart the two scans were taken.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gt_distance_m: Option<f64>,
    /// The `union` fusion's provenance line (None for the other modes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fusion: Option<String>,
    /// The scale search's provenance line (None for a single voxel).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scales: Option<String>,
    /// The scene the manifest names for it (per-scene tables).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<String>,
    /// Whether the official 3DMatch recall counts it (a gt.info entry, fragments not
    /// consecutive); its RMSE in `rmse_m` (None with no pose: a failure).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub rmse_counted: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rmse_m: Option<f64>,
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
            ..Default::default()
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
    /// The manifest the run was made on, as recorded (`manifest`; relative to where the run
    /// was started), when the file names one.
    pub manifest: Option<String>,
    pub pairs: Vec<PairRow>,
}

impl BenchRun {
    /// The run's parameters as the pipeline's own type (a `bench` run records the whole
    /// [`RegisterParams`]), read as every bench output reader reads them; the error names the
    /// run's file and the field that does not fit.
    pub fn register_params(&self) -> Result<RegisterParams> {
        crate::report::bench_file::params_from_json(Path::new(&self.label), &self.params)
    }

    /// A one-line description of the run's settings ("FPFH · geometry only · NN · SC2-PCR").
    pub fn settings_summary(&self) -> String {
        match self.register_params() {
            Ok(p) => settings_summary(&p),
            Err(e) => format!("settings not readable ({e})"),
        }
    }

    /// The recorded manifest as a path here: as recorded when it is a file (absolute, or
    /// relative to the working directory), else relative to the folder of the run file
    /// `run_file` or one of its parents (a run kept in the repository next to its manifest).
    pub fn resolve_manifest(&self, run_file: &Path) -> Option<std::path::PathBuf> {
        let m = Path::new(self.manifest.as_deref()?);
        if m.is_file() {
            return Some(m.to_path_buf());
        }
        if m.is_absolute() {
            return None;
        }
        let dir = run_file.parent()?;
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        dir.ancestors().map(|d| d.join(m)).find(|p| p.is_file())
    }
}

/// Files the settings name that are not on this machine (a VFM model, learned feature files,
/// a cached Cosmos output): a run made elsewhere cannot be re-run here without them.
pub fn missing_files(p: &RegisterParams) -> Vec<std::path::PathBuf> {
    use crate::pipeline::params::{GeoFeatureSource, WfmSpec};
    let mut files: Vec<(&Path, bool)> = Vec::new();
    match &p.geo_features {
        GeoFeatureSource::Fpfh => {}
        GeoFeatureSource::Files { source, target } => {
            files.push((source, false));
            files.push((target, false));
        }
        GeoFeatureSource::GeoTransformerPkl { path } => files.push((path, false)),
        GeoFeatureSource::Spinnet { model, .. } => files.push((model, false)),
    }
    if let Some(ib) = &p.image {
        files.push((ib.vfm.model(), false));
        if let WfmSpec::Cached { dir, spec } = &ib.backend {
            files.push((dir, true));
            files.push((spec, false));
        }
    }
    files
        .into_iter()
        .filter(|(f, dir)| if *dir { !f.is_dir() } else { !f.is_file() })
        .map(|(f, _)| f.to_path_buf())
        .collect()
}

/// A one-line description of registration settings: geometric features, image branch (WFM,
/// VFM, K), fusion, selection, estimator.
pub fn settings_summary(p: &RegisterParams) -> String {
    use super::labels;
    let mut parts = vec![format!(
        "{} (voxel {} cm)",
        labels::geo(&p.geo_features),
        (p.voxel * 1000.0).round() / 10.0
    )];
    parts.extend(labels::scales(p));
    match &p.image {
        None => parts.push("no image branch".into()),
        Some(ib) => parts.push(format!(
            "{} + {} K={}",
            labels::wfm(&ib.backend),
            labels::vfm(ib),
            ib.k
        )),
    }
    parts.push(labels::fusion(p).to_string());
    parts.push(labels::selection(p.fusion.selection));
    parts.push(p.estimator.label().to_string());
    parts.join(" | ")
}

/// Reads a `cgenreg bench --json` (or `cgenreg merge`) output through the one typed reader
/// ([`read_bench_file`](super::bench_file::read_bench_file)): errors name the file and field.
pub fn load_bench_run(path: &Path) -> Result<BenchRun> {
    let f = super::bench_file::read_bench_file(path)?;
    Ok(BenchRun::from_bench_file(&path.display().to_string(), f))
}

impl BenchRun {
    /// The comparison's view of a bench output: its identity without the parameters (compared
    /// on their own), the selected pairs (matched by id) and the shard count.
    pub fn from_bench_file(label: &str, f: super::bench_file::BenchFile) -> BenchRun {
        let mut identity = f
            .run
            .as_ref()
            .and_then(|h| serde_json::to_value(&h.identity).ok())
            .unwrap_or(Value::Null);
        if let Value::Object(m) = &mut identity {
            for k in ["params", "selected", "shard_count"] {
                m.remove(k);
            }
        }
        BenchRun {
            label: label.to_string(),
            params: f.params,
            identity,
            manifest: f.manifest,
            pairs: f.pairs,
        }
    }
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
    /// The settings behind `param_differences`: leaf paths ("fusion.selection"), or one path
    /// for a whole branch that is off in one run ("image"). More than one: the runs differ in
    /// more than the setting compared.
    pub differing_settings: Vec<String>,
    /// Other differences of the run identities (manifest, split, limit, code version).
    pub run_differences: Vec<String>,
    /// Recall of each run over the pairs in both (success / pairs with known success).
    pub recall_a: Option<f64>,
    pub recall_b: Option<f64>,
    /// Median ΔRRE / ΔRTE over the pairs with both values.
    pub median_d_rre_deg: Option<f64>,
    pub median_d_rte_m: Option<f64>,
    /// The paper-style rows of each run over the pairs in both, pooled per benchmark
    /// ([`super::bench_file::field_summaries`]); empty unless the pairs name scenes or the
    /// official 3DMatch recall counts them (manifests of the standard benchmarks).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub field_a: Vec<crate::metrics::FieldSummary>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub field_b: Vec<crate::metrics::FieldSummary>,
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
    let ab = ("in A", "in B");
    let mut by_setting = Vec::new();
    json_diff_settings("", &a.params, &b.params, ab, None, &mut by_setting);
    let mut differing_settings: Vec<String> = Vec::new();
    for (setting, _) in &by_setting {
        if !differing_settings.contains(setting) {
            differing_settings.push(setting.clone());
        }
    }
    let param_differences = by_setting.into_iter().map(|(_, l)| l).collect();
    let mut run_differences = Vec::new();
    json_diff("", &a.identity, &b.identity, ab, &mut run_differences);
    let benchmark = pairs
        .iter()
        .any(|p| p.a.scene.is_some() || p.a.rmse_counted);
    let pooled = |rows: Vec<PairRow>| -> Vec<crate::metrics::FieldSummary> {
        if !benchmark {
            return Vec::new();
        }
        super::bench_file::field_summaries(&rows)
            .into_iter()
            .filter(|f| f.scene.is_none())
            .collect()
    };
    let field_a = pooled(pairs.iter().map(|p: &PairDiff| p.a.clone()).collect());
    let field_b = pooled(pairs.iter().map(|p: &PairDiff| p.b.clone()).collect());
    Comparison {
        field_a,
        field_b,
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
        differing_settings,
        run_differences,
    }
}

/// Orders of the compared pairs (the table of `cgenreg diff` and the inspector's Compare tab).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairOrder {
    /// Flipped pairs (gained or lost) first, then by |ΔRRE|, largest first.
    FlippedFirst,
    Id,
    Flip,
    RreA,
    RreB,
    DRre,
    RteA,
    RteB,
    DRte,
}

/// Indices into `c.pairs` in `order` (`descending` reverses it; missing values go last
/// either way, ties keep A's order).
pub fn order(c: &Comparison, order: PairOrder, descending: bool) -> Vec<usize> {
    use std::cmp::Ordering;
    let mut idx: Vec<usize> = (0..c.pairs.len()).collect();
    let flip_rank = |f: Flip| match f {
        Flip::Lost => 0,
        Flip::Gained => 1,
        Flip::BothFailure => 2,
        Flip::BothSuccess => 3,
        Flip::Unknown => 4,
    };
    // missing values last in both directions
    let by_value = |x: Option<f64>, y: Option<f64>| -> Ordering {
        match (x, y) {
            (Some(x), Some(y)) => {
                let o = x.total_cmp(&y);
                if descending {
                    o.reverse()
                } else {
                    o
                }
            }
            (Some(_), None) => Ordering::Less,
            (None, Some(_)) => Ordering::Greater,
            (None, None) => Ordering::Equal,
        }
    };
    let dir = |o: Ordering| if descending { o.reverse() } else { o };
    idx.sort_by(|&i, &j| {
        let (p, q) = (&c.pairs[i], &c.pairs[j]);
        match order {
            PairOrder::FlippedFirst => {
                let flipped = |p: &PairDiff| !matches!(p.flip, Flip::Gained | Flip::Lost);
                dir(flipped(p).cmp(&flipped(q))).then(
                    q.d_rre_deg
                        .map(f64::abs)
                        .unwrap_or(-1.0)
                        .total_cmp(&p.d_rre_deg.map(f64::abs).unwrap_or(-1.0)),
                )
            }
            PairOrder::Id => dir(p.id.cmp(&q.id)),
            PairOrder::Flip => dir(flip_rank(p.flip).cmp(&flip_rank(q.flip))),
            PairOrder::RreA => by_value(p.a.rre_deg, q.a.rre_deg),
            PairOrder::RreB => by_value(p.b.rre_deg, q.b.rre_deg),
            PairOrder::DRre => by_value(p.d_rre_deg, q.d_rre_deg),
            PairOrder::RteA => by_value(p.a.rte_m, q.a.rte_m),
            PairOrder::RteB => by_value(p.b.rte_m, q.b.rte_m),
            PairOrder::DRte => by_value(p.d_rte_m, q.d_rte_m),
        }
    });
    idx
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
    for p in order(c, PairOrder::FlippedFirst, false)
        .into_iter()
        .map(|i| &c.pairs[i])
    {
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
    for (fa, fb) in c.field_a.iter().zip(&c.field_b) {
        let rmse = match (fa.rmse_recall, fb.rmse_recall) {
            (Some(x), Some(y)) => format!(
                " · RR RMSE < 0.2 m A {} % · B {} % ({} pairs)",
                f(Some(x), 100.0, 1),
                f(Some(y), 100.0, 1),
                fa.rmse_pairs
            ),
            _ => String::new(),
        };
        let fin = |v: f64| v.is_finite().then_some(v);
        let _ = writeln!(
            s,
            "{}: RR A {} % · B {} %{rmse} · RE mean (registered) A {}° · B {}° · TE mean A {} cm · B {} cm",
            fa.benchmark,
            f(Some(fa.rr), 100.0, 1),
            f(Some(fb.rr), 100.0, 1),
            f(fin(fa.re_mean_deg), 1.0, 2),
            f(fin(fb.re_mean_deg), 1.0, 2),
            f(fin(fa.te_mean_m), 100.0, 1),
            f(fin(fb.te_mean_m), 100.0, 1),
        );
    }
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
            ..Default::default()
        }
    }

    fn run(label: &str, mode: &str, pairs: Vec<PairRow>) -> BenchRun {
        BenchRun {
            label: label.into(),
            params: json!({"voxel": 0.05, "fusion": {"mode": mode}}),
            identity: json!({"manifest": "m.toml", "split": null}),
            manifest: Some("m.toml".into()),
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
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.json");
        for bad in [
            r#"{"params": {}, "summary": []}"#,
            r#"{"pairs": [{"id": 3}], "params": {}, "summary": []}"#,
        ] {
            std::fs::write(&p, bad).unwrap();
            let e = load_bench_run(&p).unwrap_err().to_string();
            assert!(e.contains("bad.json: pairs: "), "{e}");
        }
        std::fs::write(&p, b"{not json").unwrap();
        let e = load_bench_run(&p).unwrap_err().to_string();
        assert!(e.contains("bad.json"), "{e}");
    }

    fn ablation(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("studies/ablation/results")
            .join(name)
    }

    #[test]
    fn the_ablation_runs_rebuild_their_parameters_and_compare() {
        // every bench JSON of studies/ablation/results carries the whole RegisterParams
        let mut n = 0;
        for e in std::fs::read_dir(ablation("")).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "json") {
                let r = load_bench_run(&p).unwrap();
                r.register_params()
                    .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
                assert!(r.resolve_manifest(&p).is_some(), "{}", p.display());
                n += 1;
            }
        }
        assert!(n >= 10, "{n} runs");
        let a = load_bench_run(&ablation("fpfh-nn.json")).unwrap();
        let b = load_bench_run(&ablation("oracle-noisy-and-nn.json")).unwrap();
        assert_eq!(a.register_params().unwrap().image, None);
        assert!(b.register_params().unwrap().image.is_some());
        assert_eq!(
            a.settings_summary(),
            "FPFH (voxel 5 cm) | no image branch | geometry only | NN | SC2-PCR"
        );
        assert!(
            b.settings_summary().contains("oracle RGB + XFeat K=4"),
            "{}",
            b.settings_summary()
        );
        let c = compare(&a, &b);
        // FPFH NN against oracle + FPFH Noisy-AND NN: only the image branch differs, one
        // setting however many of its values
        assert_eq!(c.differing_settings, ["image"]);
        assert!(c.param_differences.len() > 3, "{:?}", c.param_differences);
        assert!(c
            .param_differences
            .iter()
            .all(|d| d.starts_with("image.") && d.chars().count() < 160));
        // the quadrants, counted here from the files' own success fields
        let raw = |p: &str| -> std::collections::HashMap<String, bool> {
            let v: Value = serde_json::from_slice(&std::fs::read(ablation(p)).unwrap()).unwrap();
            v["pairs"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| (r["id"].as_str().unwrap().to_string(), r["success"] == true))
                .collect()
        };
        let (ra, rb) = (raw("fpfh-nn.json"), raw("oracle-noisy-and-nn.json"));
        let count = |x: bool, y: bool| ra.iter().filter(|(id, s)| **s == x && rb[*id] == y).count();
        let q = c.quadrants;
        assert_eq!(
            (
                q.both_success,
                q.only_a,
                q.only_b,
                q.both_failure,
                q.unknown
            ),
            (
                count(true, true),
                count(true, false),
                count(false, true),
                count(false, false),
                0
            )
        );
        assert_eq!(c.pairs.len(), 37);
        // a second setting differs: said so
        let m = load_bench_run(&ablation("oracle-noisy-and.json")).unwrap();
        let c2 = compare(&a, &m);
        assert_eq!(c2.differing_settings, ["fusion.selection", "image"]);
        // flipped first, then by |dRRE|
        let o = order(&c, PairOrder::FlippedFirst, false);
        let flipped = o
            .iter()
            .take_while(|&&i| matches!(c.pairs[i].flip, Flip::Gained | Flip::Lost))
            .count();
        assert_eq!(flipped, q.only_a + q.only_b);
        let by = order(&c, PairOrder::DRre, true);
        let d: Vec<f64> = by.iter().filter_map(|&i| c.pairs[i].d_rre_deg).collect();
        assert!(d.windows(2).all(|w| w[0] >= w[1]));
    }

    #[test]
    fn bad_params_name_the_field() {
        let mut a = run("a", "NoisyAnd", vec![]);
        a.params = json!({"voxel": "five"});
        let e = a.register_params().unwrap_err().to_string();
        assert!(e.starts_with("a: params: "), "{e}");
        a.params = Value::Null;
        let e = a.register_params().unwrap_err().to_string();
        assert!(
            e.starts_with("a: params: ") && e.ends_with("missing"),
            "{e}"
        );
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("run.json");
        std::fs::write(
            &p,
            r#"{"pairs": [], "params": {}, "summary": [], "manifest": 3}"#,
        )
        .unwrap();
        let e = load_bench_run(&p).unwrap_err().to_string();
        assert!(e.contains("run.json: manifest: "), "{e}");
    }
}
