//! Merging shard outputs into one run file over the whole selection.

use super::{
    host_name, machine_description, now_unix, source_commit, PairRecord, RunFile, RunHeader, Shard,
    ShardRun, DONE, FAILED,
};
use crate::error::{Error, Result};

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
        return Err(Error::Missing("merge: no inputs".into()));
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
        machine: machine_description(),
        commit: source_commit(),
        // each shard's own machine and commit: a merge on a login node must not stand for
        // the compute nodes that ran the pairs
        shard_runs: inputs
            .iter()
            .map(|(name, f)| ShardRun {
                file: name.clone(),
                shard: f.run.shard,
                host: f.run.host.clone(),
                updated_unix: f.run.updated_unix,
                machine: f.run.machine.clone(),
                commit: f.run.commit.clone(),
            })
            .collect(),
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
