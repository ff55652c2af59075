//! The run file: a run's JSON output (header and one record per pair), its reader, and
//! per-stage totals over records.

use super::{RunIdentity, Shard};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunHeader {
    pub identity: RunIdentity,
    /// This output's shard (`0/1` for an unsharded or merged run).
    pub shard: Shard,
    /// Merged outputs: the shards they were made from.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub merged_from: Vec<String>,
    /// Every pair of the shard has a record (done or failed).
    pub complete: bool,
    /// The pair being run when this file was written (None between pairs and at the end).
    pub in_flight: Option<String>,
    pub host: String,
    pub updated_unix: u64,
    /// The machine: CPU model, logical cores, memory (None in files written before it was kept).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<String>,
    /// The git commit of the source tree the binary sits in, at run time ("+dirty" when its
    /// tracked files differ); None outside a git checkout. `identity.binary_blake3` names the
    /// binary itself.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub commit: Option<String>,
    /// A merged output: where, when and from which commit each shard ran, in `merged_from`'s
    /// order (the fields above are the merge's own). Empty for a shard's own output.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub shard_runs: Vec<ShardRun>,
}

/// The provenance of one shard a merged output was made from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardRun {
    /// The shard output, as named to `merge`.
    pub file: String,
    pub shard: Shard,
    pub host: String,
    pub updated_unix: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub commit: Option<String>,
}

/// One pair's outcome in a run file. `result` is the command's own per-pair JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairRecord {
    pub id: String,
    /// "done" or "failed".
    pub status: String,
    /// Why it failed (error message or panic payload).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Wall time of the pair, seconds.
    pub time_s: f64,
    /// Time per stage, milliseconds, with "cached" / "computed".
    #[serde(default)]
    pub stages: Vec<StageTime>,
    pub result: Value,
}

pub const DONE: &str = "done";
pub const FAILED: &str = "failed";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    pub stage: String,
    pub ms: f64,
    pub status: String,
}

/// What a run file holds besides the command's own summary fields: the header and one record
/// per pair, in selection order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunFile {
    pub run: RunHeader,
    pub records: Vec<PairRecord>,
}

/// Reads the `run` and `records` fields of a run file (other fields are the command's).
pub fn read_run_file(path: &Path) -> Result<RunFile> {
    // bounded, regular files only: a /dev/zero link or a FIFO is refused before any read
    let v: Value = crate::io::output::read_json(path, "run file")?;
    let f = serde_json::from_value::<RunFile>(v).map_err(|e| {
        Error::format(
            path,
            "run",
            "a cgenreg bench/study/generate output written with run and records fields",
            e.to_string(),
        )
    })?;
    f.check(path)?;
    Ok(f)
}

impl RunFile {
    /// The header and records agree with each other: a shard inside its count, the count of
    /// the identity, every record a selected pair of this shard, no pair twice. A file that
    /// fails this is corrupt (or edited), and trusting it would miscount pairs.
    pub fn check(&self, path: &Path) -> Result<()> {
        let id = &self.run.identity;
        let s = self.run.shard;
        if s.count == 0 || s.index >= s.count {
            return Err(Error::format(
                path,
                "run.shard",
                "index < count",
                format!("{}/{}", s.index, s.count),
            ));
        }
        if id.shard_count == 0 {
            return Err(Error::format(
                path,
                "run.identity.shard_count",
                "at least 1",
                "0",
            ));
        }
        let merged = !self.run.merged_from.is_empty();
        if merged && s != Shard::ALL {
            return Err(Error::format(
                path,
                "run.shard",
                "0/1 in a merged output",
                s.label(),
            ));
        }
        if !merged && s.count != id.shard_count {
            return Err(Error::format(
                path,
                "run.shard",
                format!("a shard of the run's {} shards", id.shard_count),
                s.label(),
            ));
        }
        let mut seen = std::collections::HashSet::new();
        for (i, r) in self.records.iter().enumerate() {
            let Some(pos) = id.selected.iter().position(|x| *x == r.id) else {
                return Err(Error::format(
                    path,
                    format!("records[{i}].id"),
                    "a pair of run.identity.selected",
                    format!("{:?}", r.id),
                ));
            };
            if !merged && !s.contains(pos) {
                return Err(Error::format(
                    path,
                    format!("records[{i}].id"),
                    format!("a pair of shard {s}"),
                    format!("{:?} (position {pos} in the selection)", r.id),
                ));
            }
            if !seen.insert(pos) {
                return Err(Error::format(
                    path,
                    format!("records[{i}].id"),
                    "each pair once",
                    format!("{:?} again", r.id),
                ));
            }
            if r.status != DONE && r.status != FAILED {
                return Err(Error::format(
                    path,
                    format!("records[{i}].status"),
                    "\"done\" or \"failed\"",
                    format!("{:?}", r.status),
                ));
            }
        }
        Ok(())
    }
}

impl PairRecord {
    /// The result with every timing field removed (timings differ between runs).
    pub fn result_without_times(&self) -> Value {
        strip_times(&self.result)
    }
}

/// `v` without object fields named `time_s`, `ms` or ending in `_ms` / `_s`... only the
/// timing fields cgenreg writes: `time_s`, `ms`, `total_ms`, `time_per_pair_s`.
pub fn strip_times(v: &Value) -> Value {
    match v {
        Value::Object(m) => Value::Object(
            m.iter()
                .filter(|(k, _)| {
                    !matches!(k.as_str(), "time_s" | "ms" | "total_ms" | "time_per_pair_s")
                })
                .map(|(k, x)| (k.clone(), strip_times(x)))
                .collect(),
        ),
        Value::Array(a) => Value::Array(a.iter().map(strip_times).collect()),
        other => other.clone(),
    }
}

/// Per-stage time over records: (stage, total ms, pairs computed, pairs cached), in order of
/// first appearance.
pub fn stage_totals<'a>(
    records: impl IntoIterator<Item = &'a PairRecord>,
) -> Vec<(String, f64, usize, usize)> {
    let mut out: Vec<(String, f64, usize, usize)> = Vec::new();
    for r in records {
        for s in &r.stages {
            let cached = crate::pipeline::result::is_cached(&s.status);
            match out.iter_mut().find(|x| x.0 == s.stage) {
                Some(x) => {
                    x.1 += s.ms;
                    x.2 += !cached as usize;
                    x.3 += cached as usize;
                }
                None => out.push((s.stage.clone(), s.ms, !cached as usize, cached as usize)),
            }
        }
    }
    out
}
