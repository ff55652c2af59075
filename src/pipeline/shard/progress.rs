//! A run in progress: resume from an existing output, the records so far, the atomic rewrite
//! after every pair, and the pending pairs run through the shared pair loop.

use super::{
    host_name, machine_description, now_unix, read_run_file, source_commit, PairRecord, RunFile,
    RunHeader, RunIdentity, Shard, DONE, FAILED,
};
use crate::error::{Error, Result};
use serde_json::Value;
use std::path::{Path, PathBuf};

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
    /// The output's lock, held while the run lasts: a second process given the same output
    /// is refused rather than both overwriting each other's records.
    _lock: Option<crate::io::output::OutputLock>,
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
        let lock = path.map(crate::io::output::lock).transpose()?;
        let n = identity.selected.len();
        let positions = shard.positions(n);
        let mut records: Vec<Option<PairRecord>> = vec![None; n];
        let mut message = None;
        if let (Some(p), ResumeMode::Resume) = (path, mode) {
            if std::fs::symlink_metadata(p).is_ok() {
                let old = read_run_file(p).map_err(|e| {
                    Error::Invalid(format!(
                        "{e}\n{} cannot be resumed: remove it to run this shard from the \
                         start",
                        p.display()
                    ))
                })?;
                let diffs = old.run.identity.differences(&identity);
                if !diffs.is_empty() || old.run.shard != shard {
                    let mut d = diffs;
                    if old.run.shard != shard {
                        d.push(format!(
                            "shard: {} here, {shard} there",
                            old.run.shard.label()
                        ));
                    }
                    return Err(Error::Usage(format!(
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
            machine: machine_description(),
            commit: source_commit(),
            shard_runs: Vec::new(),
        };
        Ok((
            Progress {
                path: path.map(Path::to_path_buf),
                header,
                records,
                positions,
                _lock: lock,
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
            // `--force` was judged when the run started (the file is this run's since): links,
            // FIFOs and folders planted meanwhile are still refused
            crate::io::output::write(p, crate::io::output::OutputKind::RunJson, true, &bytes)?;
        }
        Ok(())
    }
}

/// A run's state shared by the pair loop's hooks: the progress, the log, the pairs done so far
/// and the last write problem (warned about once, the run goes on).
struct Pending<'a> {
    progress: &'a mut Progress,
    log: &'a mut dyn FnMut(&str),
    done: usize,
    write_problem: Option<String>,
}

impl Pending<'_> {
    /// Notes the outcome of a write of the output.
    fn saved(&mut self, r: Result<()>) {
        if let Err(e) = r {
            if self.write_problem.is_none() {
                (self.log)(&format!(
                    "warning: could not write the output: {e} (the run goes on)"
                ));
            }
            self.write_problem = Some(e.to_string());
        } else {
            self.write_problem = None;
        }
    }
}

/// Runs the pending pairs of `progress` one after the other through the
/// [pair loop](crate::pipeline::pair_loop::run_items): marks each in flight, runs
/// `run(position, id)` under [`catch_panic`](crate::error::catch_panic), records the outcome (a failure as
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
    let pending: Vec<(usize, String)> = progress
        .pending()
        .into_iter()
        .map(|pos| (pos, progress.id(pos).to_string()))
        .collect();
    let total = progress.positions.len();
    let shard = progress.header.shard;
    let mut state = Pending {
        done: total - pending.len(),
        progress,
        log,
        write_problem: None,
    };
    crate::pipeline::pair_loop::run_items(
        &mut state,
        &pending,
        None,
        |s, _, (pos, _)| {
            let r = s.progress.begin(*pos, write);
            s.saved(r);
        },
        |_, _, (pos, id)| run(*pos, id),
        |s, _, (pos, id), r, elapsed| {
            let rec = match r {
                Ok(rec) => rec,
                Err(e) => PairRecord {
                    id: id.clone(),
                    status: FAILED.into(),
                    error: Some(e.to_string()),
                    time_s: elapsed.as_secs_f64(),
                    stages: Vec::new(),
                    result: failed_result(*pos, &e.to_string()),
                },
            };
            s.done += 1;
            let line = match &rec.error {
                None => format!(
                    "[shard {shard}] {}/{total} {id}: done in {:.2} s",
                    s.done, rec.time_s
                ),
                Some(e) => format!("[shard {shard}] {}/{total} {id}: FAILED: {e}", s.done),
            };
            (s.log)(&line);
            let r = s.progress.finish(*pos, rec, write);
            s.saved(r);
        },
    );
    let r = state.progress.save(write);
    state.saved(r);
    match state.write_problem {
        Some(e) => Err(Error::Invalid(format!(
            "the output could not be written: {e}"
        ))),
        None => Ok(()),
    }
}
