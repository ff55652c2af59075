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
//!
//! Files: this one holds [`Shard`] and [`RunIdentity`]; `run_file.rs` the output's format
//! ([`RunFile`], [`PairRecord`]) and reader; `progress.rs` a run in progress ([`Progress`],
//! [`run_pending`]); `merge.rs` the merge of shard outputs ([`merge`]).

mod merge;
mod progress;
mod run_file;
#[cfg(test)]
mod tests;

pub use merge::{merge, Merged};
pub use progress::{run_pending, Progress, ResumeMode};
pub use run_file::{
    read_run_file, stage_totals, strip_times, PairRecord, RunFile, RunHeader, ShardRun, StageTime,
    DONE, FAILED,
};

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

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
            manifest_blake3: crate::cache::hash_file(manifest)?,
            split: split.map(str::to_string),
            limit,
            params: crate::cache::canonical(&params),
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
        crate::io::json_diff::json_diff("", &a, &b, ("here", "there"), &mut out);
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
        crate::cache::hash_file(&exe).map_err(|e| e.to_string())
    })
    .clone()
    .map_err(Error::Invalid)
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "unknown".into())
}

/// "CPU model, N logical cores, M GiB" from /proc (None where it cannot be read).
fn machine_description() -> Option<String> {
    let cpu = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let model = cpu
        .lines()
        .find_map(|l| l.strip_prefix("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, m)| m.trim().to_string())
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let mem_gib = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            m.lines()
                .find_map(|l| l.strip_prefix("MemTotal:"))
                .and_then(|v| v.split_whitespace().next()?.parse::<f64>().ok())
        })
        .map_or(String::new(), |kib| {
            format!(", {:.1} GiB", kib / 1024.0 / 1024.0)
        });
    Some(format!("{model}, {cores} logical cores{mem_gib}"))
}

/// The commit of the git checkout the running executable sits in (its nearest ancestor folder
/// with `.git`), "+dirty" when tracked files differ; once per process. Arguments go to git
/// directly, never through a shell.
fn source_commit() -> Option<String> {
    static COMMIT: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    COMMIT
        .get_or_init(|| {
            let exe = std::env::current_exe().ok()?;
            let repo = exe.ancestors().skip(1).find(|d| d.join(".git").exists())?;
            let git = |args: &[&str]| -> Option<String> {
                let o = std::process::Command::new("git")
                    .arg("-C")
                    .arg(repo)
                    .args(args)
                    .stderr(std::process::Stdio::null())
                    .output()
                    .ok()?;
                o.status
                    .success()
                    .then(|| String::from_utf8_lossy(&o.stdout).trim().to_string())
            };
            let rev = git(&["rev-parse", "HEAD"]).filter(|r| !r.is_empty())?;
            let dirty = git(&["status", "--porcelain", "--untracked-files=no"])
                .is_some_and(|s| !s.is_empty());
            Some(if dirty { format!("{rev}+dirty") } else { rev })
        })
        .clone()
}

fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}
