//! Sharded, resumable runs over a manifest's pairs (`bench`, `study`, `generate`), and the
//! merge of their shard outputs.
//!
//! **Shards.** `--shard I/N` (0 <= I < N) keeps the selected pairs whose position p in the
//! selection (after `--split` and `--limit`, in manifest order) has `p mod N == I`. The N shards
//! are a partition of the selection: every pair is in exactly one, and the shards' sizes differ
//! by at most one. Slurm's `$SLURM_ARRAY_TASK_ID` (0..N-1 with `--array=0-(N-1)`) is I.
//!
//! **Resumable output.** A run's JSON output (a [`RunFile`]) is rewritten atomically (temporary
//! file in the same directory, then rename) after every pair, so a killed run loses at most the
//! pair in flight. A re-run with the same parameters reads it back and runs only the pairs not
//! done yet (pairs recorded as failed are run again); with other parameters it refuses and says
//! what differs.
//!
//! **Identity.** What must match for a resume or a merge: the command, the manifest (path and
//! content hash), the selection (`--split`, `--limit`), the parameters, the shard count, the
//! code version and the binary's content hash ([`RunIdentity`]).

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// `--shard I/N`: this process runs shard `index` of `count`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Default for Shard {
    fn default() -> Self {
        Shard::ALL
    }
}

impl Shard {
    /// The whole selection (one shard).
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Whether the pair at `position` in the selection belongs to this shard.
    pub fn contains(&self, position: usize) -> bool {
        position % self.count == self.index
    }

    /// The positions of this shard among `n` selected pairs.
    pub fn positions(&self, n: usize) -> Vec<usize> {
        (self.index..n).step_by(self.count).collect()
    }

    /// "2/3".
    pub fn label(&self) -> String {
        format!("{}/{}", self.index, self.count)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Shard, String> {
        let bad = || format!("--shard {s:?}: expected I/N with 0 <= I < N, e.g. 0/3");
        let (i, n) = s.trim().split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

/// Everything that must be equal for two outputs to be parts of one run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunIdentity {
    /// "bench", "study k", "study prompt", "generate".
    pub command: String,
    /// The manifest path as given, and the blake3 of its content.
    pub manifest: String,
    pub manifest_blake3: String,
    pub split: Option<String>,
    pub limit: Option<usize>,
    /// The run's parameters (pipeline, image branch, study settings), as JSON.
    pub params: Value,
    pub shard_count: usize,
    /// "cgenreg 0.1.0".
    pub code_version: String,
    /// blake3 of the running executable: the same source built another way is another code.
    pub binary_blake3: String,
    /// Every selected pair id, in selection order (all shards).
    pub selected: Vec<String>,
}

impl RunIdentity {
    /// The identity of a run of `command` over `selected` pairs of `manifest`.
    pub fn new(
        command: &str,
        manifest: &Path,
        split: Option<&str>,
        limit: Option<usize>,
        params: Value,
        shard_count: usize,
        selected: Vec<String>,
    ) -> Result<RunIdentity> {
        Ok(RunIdentity {
            command: command.to_string(),
            manifest: manifest.display().to_string(),
            manifest_blake3: super::cache::hash_file(manifest)?,
            split: split.map(str::to_string),
            limit,
            params: super::cache::canonical(&params),
            shard_count,
            code_version: code_version(),
            binary_blake3: binary_hash()?,
            selected,
        })
    }

    /// What differs from `other`, one line per difference (empty when equal).
    pub fn differences(&self, other: &RunIdentity) -> Vec<String> {
        let a = serde_json::to_value(self).unwrap_or(Value::Null);
        let b = serde_json::to_value(other).unwrap_or(Value::Null);
        let mut out = Vec::new();
        crate::metrics::compare::json_diff("", &a, &b, ("here", "there"), &mut out);
        out
    }
}

/// "cgenreg 0.1.0".
pub fn code_version() -> String {
    format!("cgenreg {}", env!("CARGO_PKG_VERSION"))
}

/// blake3 of the running executable (computed once per process).
pub fn binary_hash() -> Result<String> {
    static HASH: std::sync::OnceLock<std::result::Result<String, String>> =
        std::sync::OnceLock::new();
    HASH.get_or_init(|| {
        let exe = std::env::current_exe().map_err(|e| format!("the running executable: {e}"))?;
        super::cache::hash_file(&exe).map_err(|e| e.to_string())
    })
    .clone()
    .map_err(Error::Invalid)
}

/// The header of a run's JSON output (the `run` field).
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
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    serde_json::from_slice::<RunFile>(&bytes).map_err(|e| {
        Error::format(
            path,
            "run",
            "a cgenreg bench/study/generate output written with run and records fields",
            e.to_string(),
        )
    })
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "unknown".into())
}

fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// How a run starts when its output exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResumeMode {
    /// Keep the pairs done with the same identity (the default).
    Resume,
    /// Ignore the existing output and run every pair.
    Restart,
}

/// A run in progress: its records so far, rewritten to `path` after each pair.
pub struct Progress {
    pub path: Option<PathBuf>,
    pub header: RunHeader,
    /// Records by position in the selection (None: not run yet).
    records: Vec<Option<PairRecord>>,
    /// Positions (in the selection) this shard runs.
    pub positions: Vec<usize>,
}

impl Progress {
    /// Starts (or resumes, reading `path`) the run of `shard` of `identity`'s selection.
    /// Returns the progress and a message for the log when an existing output was read.
    pub fn start(
        identity: RunIdentity,
        shard: Shard,
        path: Option<&Path>,
        mode: ResumeMode,
    ) -> Result<(Progress, Option<String>)> {
        if identity.shard_count != shard.count {
            return Err(Error::Invalid(format!(
                "shard {shard} but the identity says {} shards",
                identity.shard_count
            )));
        }
        let n = identity.selected.len();
        let positions = shard.positions(n);
        let mut records: Vec<Option<PairRecord>> = vec![None; n];
        let mut message = None;
        if let (Some(p), ResumeMode::Resume) = (path, mode) {
            if p.exists() {
                let old = read_run_file(p)?;
                let diffs = old.run.identity.differences(&identity);
                if !diffs.is_empty() || old.run.shard != shard {
                    let mut d = diffs;
                    if old.run.shard != shard {
                        d.push(format!(
                            "shard: {} here, {shard} there",
                            old.run.shard.label()
                        ));
                    }
                    return Err(Error::Invalid(format!(
                        "{} holds a run with other parameters, so it cannot be resumed:\n  {}\n\
                         pass --no-resume to start over (it is then overwritten), or choose \
                         another output",
                        p.display(),
                        d.join("\n  ")
                    )));
                }
                let (mut done, mut failed) = (0, 0);
                for r in old.records {
                    if let Some(pos) = identity.selected.iter().position(|id| *id == r.id) {
                        if shard.contains(pos) && r.status == DONE {
                            done += 1;
                            records[pos] = Some(r);
                        } else if r.status == FAILED {
                            failed += 1;
                        }
                    }
                }
                let left = positions.len() - done;
                message = Some(format!(
                    "resuming {}: {done} of {} pairs of shard {shard} done{}, {left} to run \
                     (--no-resume starts over)",
                    p.display(),
                    positions.len(),
                    if failed > 0 {
                        format!(", {failed} failed before (run again)")
                    } else {
                        String::new()
                    }
                ));
            }
        }
        let header = RunHeader {
            identity,
            shard,
            merged_from: Vec::new(),
            complete: false,
            in_flight: None,
            host: host_name(),
            updated_unix: now_unix(),
        };
        Ok((
            Progress {
                path: path.map(Path::to_path_buf),
                header,
                records,
                positions,
            },
            message,
        ))
    }

    /// The positions still to run, in order.
    pub fn pending(&self) -> Vec<usize> {
        self.positions
            .iter()
            .copied()
            .filter(|&p| self.records[p].is_none())
            .collect()
    }

    /// The pair id at `position`.
    pub fn id(&self, position: usize) -> &str {
        &self.header.identity.selected[position]
    }

    /// Records so far, in selection order.
    pub fn records(&self) -> Vec<&PairRecord> {
        self.records.iter().flatten().collect()
    }

    /// Marks `position` as in flight (written out, so a status reader sees it).
    pub fn begin(
        &mut self,
        position: usize,
        write: &dyn Fn(&RunFile) -> Result<Vec<u8>>,
    ) -> Result<()> {
        self.header.in_flight = Some(self.id(position).to_string());
        self.save(write)
    }

    /// Records a pair's outcome and rewrites the output.
    pub fn finish(
        &mut self,
        position: usize,
        record: PairRecord,
        write: &dyn Fn(&RunFile) -> Result<Vec<u8>>,
    ) -> Result<()> {
        self.records[position] = Some(record);
        self.header.in_flight = None;
        self.header.complete = self.positions.iter().all(|&p| self.records[p].is_some());
        self.save(write)
    }

    pub fn run_file(&self) -> RunFile {
        RunFile {
            run: self.header.clone(),
            records: self.records().into_iter().cloned().collect(),
        }
    }

    /// Writes the output (atomically) through the command's serialiser `write`.
    pub fn save(&mut self, write: &dyn Fn(&RunFile) -> Result<Vec<u8>>) -> Result<()> {
        self.header.updated_unix = now_unix();
        self.header.complete = self.positions.iter().all(|&p| self.records[p].is_some());
        if let Some(p) = &self.path {
            let bytes = write(&self.run_file())?;
            crate::error::write_atomic(p, &bytes)?;
        }
        Ok(())
    }
}

/// Runs `f` and turns a panic into an error carrying the panic message (a last-resort guard
/// around one pair: the run records the pair as failed and goes on).
pub fn catch_pair<T>(f: impl FnOnce() -> Result<T>) -> Result<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(payload) => {
            let msg = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".into());
            Err(Error::Invalid(format!("panicked: {msg}")))
        }
    }
}

/// Runs the pending pairs of `progress` one after the other: marks each in flight, runs
/// `run(position, id)` under [`catch_pair`], records the outcome (a failure as
/// `failed_result(position, reason)`), and rewrites the output. A pair that errors or panics is
/// recorded as failed and the run goes on; `log` gets one line per pair for a log reader.
/// Errors only when the output cannot be written at the end.
pub fn run_pending(
    progress: &mut Progress,
    write: &dyn Fn(&RunFile) -> Result<Vec<u8>>,
    run: &mut dyn FnMut(usize, &str) -> Result<PairRecord>,
    failed_result: &dyn Fn(usize, &str) -> Value,
    log: &mut dyn FnMut(&str),
) -> Result<()> {
    let pending = progress.pending();
    let total = progress.positions.len();
    let mut done = total - pending.len();
    let shard = progress.header.shard;
    let mut write_problem: Option<String> = None;
    let mut save = |r: Result<()>, log: &mut dyn FnMut(&str)| {
        if let Err(e) = r {
            if write_problem.is_none() {
                log(&format!(
                    "warning: could not write the output: {e} (the run goes on)"
                ));
            }
            write_problem = Some(e.to_string());
        } else {
            write_problem = None;
        }
    };
    for pos in pending {
        let id = progress.id(pos).to_string();
        let r = progress.begin(pos, write);
        save(r, log);
        let t = std::time::Instant::now();
        let rec = match catch_pair(|| run(pos, &id)) {
            Ok(rec) => rec,
            Err(e) => PairRecord {
                id: id.clone(),
                status: FAILED.into(),
                error: Some(e.to_string()),
                time_s: t.elapsed().as_secs_f64(),
                stages: Vec::new(),
                result: failed_result(pos, &e.to_string()),
            },
        };
        done += 1;
        log(&match &rec.error {
            None => format!(
                "[shard {shard}] {done}/{total} {id}: done in {:.2} s",
                rec.time_s
            ),
            Some(e) => format!("[shard {shard}] {done}/{total} {id}: FAILED: {e}"),
        });
        let r = progress.finish(pos, rec, write);
        save(r, log);
    }
    let r = progress.save(write);
    save(r, log);
    match write_problem {
        Some(e) => Err(Error::Invalid(format!(
            "the output could not be written: {e}"
        ))),
        None => Ok(()),
    }
}

/// The result of merging shard outputs: one run file over the whole selection, plus what is
/// wrong with it.
pub struct Merged {
    pub file: RunFile,
    /// Selected pairs no shard has a record for.
    pub missing: Vec<String>,
    /// Pairs with records in several inputs: (id, the inputs).
    pub duplicated: Vec<(String, Vec<String>)>,
    pub failed: Vec<(String, String)>,
}

/// Merges run files (labelled by their paths). All must have the same identity; a pair found
/// in several inputs is kept once when its results agree and is an error when they differ.
pub fn merge(inputs: &[(String, RunFile)]) -> Result<Merged> {
    let Some((first_name, first)) = inputs.first() else {
        return Err(Error::Invalid("merge: no inputs".into()));
    };
    let id = &first.run.identity;
    for (name, f) in &inputs[1..] {
        let d = f.run.identity.differences(id);
        if !d.is_empty() {
            return Err(Error::Invalid(format!(
                "{name} and {first_name} are not parts of one run (\"here\" = {name}):\n  {}",
                d.join("\n  ")
            )));
        }
    }
    let n = id.selected.len();
    let mut slots: Vec<Option<(PairRecord, Vec<String>)>> = vec![None; n];
    for (name, f) in inputs {
        for r in &f.records {
            let Some(pos) = id.selected.iter().position(|s| *s == r.id) else {
                return Err(Error::Invalid(format!(
                    "{name}: pair {} is not in the run's selection",
                    r.id
                )));
            };
            match &mut slots[pos] {
                None => slots[pos] = Some((r.clone(), vec![name.clone()])),
                Some((kept, names)) => {
                    names.push(name.clone());
                    // A failed record gives way to a done one (a re-run that succeeded).
                    if kept.status == FAILED && r.status == DONE {
                        *kept = r.clone();
                    } else if kept.status == DONE
                        && r.status == DONE
                        && kept.result_without_times() != r.result_without_times()
                    {
                        return Err(Error::Invalid(format!(
                            "pair {} has different results in {}",
                            r.id,
                            names.join(" and ")
                        )));
                    }
                }
            }
        }
    }
    let mut missing = Vec::new();
    let mut duplicated = Vec::new();
    let mut failed = Vec::new();
    let mut records = Vec::new();
    for (pos, s) in slots.into_iter().enumerate() {
        match s {
            None => missing.push(id.selected[pos].clone()),
            Some((r, names)) => {
                if names.len() > 1 {
                    duplicated.push((r.id.clone(), names));
                }
                if r.status == FAILED {
                    failed.push((r.id.clone(), r.error.clone().unwrap_or_default()));
                }
                records.push(r);
            }
        }
    }
    let header = RunHeader {
        identity: id.clone(),
        shard: Shard::ALL,
        merged_from: inputs.iter().map(|(n, _)| n.clone()).collect(),
        complete: missing.is_empty(),
        in_flight: None,
        host: host_name(),
        updated_unix: now_unix(),
    };
    Ok(Merged {
        file: RunFile {
            run: header,
            records,
        },
        missing,
        duplicated,
        failed,
    })
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
            let cached = super::result::is_cached(&s.status);
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

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn identity(n: usize, count: usize) -> RunIdentity {
        RunIdentity {
            command: "bench".into(),
            manifest: "m.toml".into(),
            manifest_blake3: "abc".into(),
            split: None,
            limit: None,
            params: json!({"voxel": 0.05, "fusion": {"mode": "NoisyAnd"}}),
            shard_count: count,
            code_version: code_version(),
            binary_blake3: "bin".into(),
            selected: (0..n).map(|i| format!("d/{i}-{}", i + 1)).collect(),
        }
    }

    fn record(id: &str, status: &str, rre: f64) -> PairRecord {
        PairRecord {
            id: id.into(),
            status: status.into(),
            error: (status == FAILED).then(|| "boom".to_string()),
            time_s: 1.5,
            stages: vec![StageTime {
                stage: "generation".into(),
                ms: 1000.0,
                status: "computed".into(),
            }],
            result: json!({"rre_deg": rre, "time_s": 1.5}),
        }
    }

    #[test]
    fn shard_parse() {
        assert_eq!(
            "2/3".parse::<Shard>().unwrap(),
            Shard { index: 2, count: 3 }
        );
        assert_eq!(" 0 / 1 ".parse::<Shard>().unwrap(), Shard::ALL);
        for bad in ["3/3", "1/0", "a/2", "1", "-1/2", "1/2/3", ""] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn shards_partition_the_selection() {
        // Every n and N up to 40: each position in exactly one shard, sizes within one.
        for n in 0..40 {
            for count in 1..12 {
                let mut seen = vec![0usize; n];
                let mut sizes = Vec::new();
                for index in 0..count {
                    let s = Shard { index, count };
                    let p = s.positions(n);
                    assert!(p.iter().all(|&q| s.contains(q)));
                    assert!(p.windows(2).all(|w| w[0] < w[1]));
                    sizes.push(p.len());
                    for q in p {
                        seen[q] += 1;
                    }
                }
                assert!(seen.iter().all(|&c| c == 1), "n {n} N {count}: {seen:?}");
                let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
                assert!(hi - lo <= 1, "n {n} N {count}: {sizes:?}");
            }
        }
    }

    fn shard_file(id: &RunIdentity, index: usize, recs: Vec<PairRecord>) -> RunFile {
        RunFile {
            run: RunHeader {
                identity: id.clone(),
                shard: Shard {
                    index,
                    count: id.shard_count,
                },
                merged_from: vec![],
                complete: true,
                in_flight: None,
                host: "h".into(),
                updated_unix: 0,
            },
            records: recs,
        }
    }

    #[test]
    fn merge_orders_and_reports_missing_and_duplicates() {
        let id = identity(5, 2);
        let s = &id.selected;
        let a = shard_file(
            &id,
            0,
            vec![
                record(&s[0], DONE, 1.0),
                record(&s[2], DONE, 3.0),
                record(&s[4], FAILED, 0.0),
            ],
        );
        // shard 1 lacks pair 3 and repeats pair 2 with the same result
        let b = shard_file(
            &id,
            1,
            vec![record(&s[1], DONE, 2.0), record(&s[2], DONE, 3.0)],
        );
        let m = merge(&[("a".into(), a.clone()), ("b".into(), b)]).unwrap();
        let ids: Vec<&str> = m.file.records.iter().map(|r| r.id.as_str()).collect();
        assert_eq!(ids, [&s[0], &s[1], &s[2], &s[4]]);
        assert_eq!(m.missing, vec![s[3].clone()]);
        assert_eq!(
            m.duplicated,
            vec![(s[2].clone(), vec!["a".into(), "b".into()])]
        );
        assert_eq!(m.failed, vec![(s[4].clone(), "boom".into())]);
        assert!(!m.file.run.complete);

        // the same pair with another result is an error naming both inputs
        let c = shard_file(&id, 1, vec![record(&s[2], DONE, 9.0)]);
        let e = merge(&[("a".into(), a.clone()), ("c".into(), c)])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains(&s[2]) && e.contains("a and c"), "{e}");

        // a re-run that succeeded replaces the failure
        let d = shard_file(&id, 0, vec![record(&s[4], DONE, 5.0)]);
        let m = merge(&[("a".into(), a), ("d".into(), d)]).unwrap();
        assert!(m.failed.is_empty());
        assert_eq!(m.file.records.last().unwrap().status, DONE);
    }

    #[test]
    fn merge_refuses_other_parameters_and_says_what_differs() {
        let id = identity(4, 2);
        let mut other = id.clone();
        other.params = json!({"voxel": 0.1, "fusion": {"mode": "NoisyAnd"}});
        other.binary_blake3 = "other".into();
        let e = merge(&[
            ("a".into(), shard_file(&id, 0, vec![])),
            ("b".into(), shard_file(&other, 1, vec![])),
        ])
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("params.voxel: 0.1 here, 0.05 there"), "{e}");
        assert!(e.contains("binary_blake3"), "{e}");
        assert!(!e.contains("fusion"), "{e}");
        let mut n3 = id.clone();
        n3.shard_count = 3;
        let e = merge(&[
            ("a".into(), shard_file(&id, 0, vec![])),
            ("b".into(), shard_file(&n3, 1, vec![])),
        ])
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("shard_count: 3 here, 2 there"), "{e}");
    }

    #[test]
    fn progress_resumes_only_matching_runs() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r.json");
        let id = identity(7, 2);
        let shard = Shard { index: 1, count: 2 };
        let ser = |f: &RunFile| Ok(serde_json::to_vec(f).unwrap());
        let (mut p, msg) =
            Progress::start(id.clone(), shard, Some(&out), ResumeMode::Resume).unwrap();
        assert!(msg.is_none());
        assert_eq!(p.pending(), vec![1, 3, 5]);
        p.begin(1, &ser).unwrap();
        assert_eq!(
            read_run_file(&out).unwrap().run.in_flight.as_deref(),
            Some(id.selected[1].as_str())
        );
        p.finish(1, record(&id.selected[1], DONE, 1.0), &ser)
            .unwrap();
        p.finish(3, record(&id.selected[3], FAILED, 0.0), &ser)
            .unwrap();
        drop(p); // "killed" here: pair 5 never ran

        let (p, msg) = Progress::start(id.clone(), shard, Some(&out), ResumeMode::Resume).unwrap();
        let msg = msg.unwrap();
        assert!(
            msg.contains("1 of 3 pairs") && msg.contains("1 failed"),
            "{msg}"
        );
        assert_eq!(p.pending(), vec![3, 5]);
        let (p, _) = Progress::start(id.clone(), shard, Some(&out), ResumeMode::Restart).unwrap();
        assert_eq!(p.pending(), vec![1, 3, 5]);

        let mut other = id.clone();
        other.params["voxel"] = json!(0.025);
        let e = Progress::start(other, shard, Some(&out), ResumeMode::Resume)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("--no-resume") && e.contains("params.voxel"),
            "{e}"
        );
        let e = Progress::start(
            id,
            Shard { index: 0, count: 2 },
            Some(&out),
            ResumeMode::Resume,
        )
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("shard"), "{e}");
    }

    #[test]
    fn a_panicking_or_failing_pair_is_recorded_and_the_run_goes_on() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r.json");
        let id = identity(4, 1);
        let ser = |f: &RunFile| Ok(serde_json::to_vec(f).unwrap());
        let (mut p, _) =
            Progress::start(id.clone(), Shard::ALL, Some(&out), ResumeMode::Resume).unwrap();
        let mut lines = Vec::new();
        run_pending(
            &mut p,
            &ser,
            &mut |pos, pid| match pos {
                1 => panic!("index out of bounds in a reader"),
                2 => Err(Error::Invalid("bad file".into())),
                _ => Ok(record(pid, DONE, pos as f64)),
            },
            &|pos, why| json!({"pos": pos, "why": why}),
            &mut |l| lines.push(l.to_string()),
        )
        .unwrap();
        let f = read_run_file(&out).unwrap();
        assert!(f.run.complete && f.run.in_flight.is_none());
        let st: Vec<&str> = f.records.iter().map(|r| r.status.as_str()).collect();
        assert_eq!(st, [DONE, FAILED, FAILED, DONE]);
        assert!(f.records[1]
            .error
            .as_ref()
            .unwrap()
            .contains("index out of bounds"));
        assert!(f.records[2].result["why"]
            .as_str()
            .unwrap()
            .contains("bad file"));
        assert_eq!(lines.len(), 4);
        assert!(
            lines[1].contains("FAILED") && lines[1].contains(&id.selected[1]),
            "{lines:?}"
        );
    }

    #[test]
    fn catch_pair_turns_panics_into_errors() {
        let e = catch_pair::<()>(|| panic!("reader exploded at byte {}", 7))
            .unwrap_err()
            .to_string();
        assert!(e.contains("reader exploded at byte 7"), "{e}");
        assert_eq!(catch_pair(|| Ok(3)).unwrap(), 3);
    }

    #[test]
    fn strip_times_removes_only_timings() {
        let v = json!({"time_s": 1, "rre_deg": 2, "x": [{"ms": 3, "stage": "a"}]});
        assert_eq!(
            strip_times(&v),
            json!({"rre_deg": 2, "x": [{"stage": "a"}]})
        );
    }
}
