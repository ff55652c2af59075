//! `cgenreg merge` (shard outputs into one run) and `cgenreg status` (pairs done / failed /
//! missing per shard, time per stage, projected cost of a full run).

use crate::error::{Error, Result};
use crate::io::output::OutputKind;
use crate::pipeline::shard::{merge, read_run_file, stage_totals, PairRecord, RunFile, FAILED};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct MergeArgs {
    /// Shard outputs (`bench --json` / `study --json` / `generate --json` of one run), or
    /// run folders (their `*.json` and `shards/*.json`).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Write the merged output here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Replace an existing --json file even when it is not a cgenreg run file.
    #[arg(long)]
    pub force: bool,
    /// Exit 0 even when pairs are missing (the merged output then says complete: false).
    #[arg(long)]
    pub allow_missing: bool,
}

#[derive(Args, Debug)]
pub struct StatusArgs {
    /// A run folder (`cgenreg slurm --out DIR`: its `shards/*.json`), or shard outputs.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// Pairs of the full run to project the cost for (3DMatch's test set has 1,623).
    #[arg(long, default_value_t = 1623)]
    pub project_pairs: usize,
}

/// Prints the command's own table for a (merged) run file.
fn print_tables(f: &RunFile) -> Result<()> {
    match f.run.identity.command.as_str() {
        "bench" => {
            super::bench::print_table(&super::bench::summarise(&super::bench::rows_of(f)?));
        }
        c if c.starts_with("study") => super::study::print_study(f)?,
        _ => {}
    }
    outln!();
    super::bench::print_stage_table(&f.records);
    Ok(())
}

pub fn run_merge(a: MergeArgs) -> Result<()> {
    if let Some(path) = &a.json {
        crate::io::output::prepare(path, OutputKind::RunJson, a.force)?;
    }
    let (good, corrupt) = collect(&a.inputs)?;
    if !corrupt.is_empty() {
        for (p, why) in &corrupt {
            eprintln!("corrupt: {}: {why}", p.display());
        }
        return Err(Error::Invalid(format!(
            "{} run file(s) cannot be read (listed above): {}; nothing was merged. Remove \
             them, then run their shards again (a shard without output starts over)",
            corrupt.len(),
            names(&corrupt)
        )));
    }
    if good.is_empty() {
        return Err(no_outputs(&a.inputs));
    }
    let inputs: Vec<(String, RunFile)> = good
        .into_iter()
        .map(|(p, f)| (p.display().to_string(), f))
        .collect();
    let mut shards: Vec<(usize, &str)> = inputs
        .iter()
        .map(|(n, f)| (f.run.shard.index, n.as_str()))
        .collect();
    shards.sort();
    let m = merge(&inputs)?;
    let count = m.file.run.identity.shard_count;
    let present: Vec<usize> = shards.iter().map(|s| s.0).collect();
    let absent: Vec<String> = (0..count)
        .filter(|i| !present.contains(i))
        .map(|i| format!("{i}/{count}"))
        .collect();
    print_tables(&m.file)?;
    eprintln!(
        "merged {} outputs of a {count}-shard {} run: {} of {} pairs ({} failed){}",
        inputs.len(),
        m.file.run.identity.command,
        m.file.records.len(),
        m.file.run.identity.selected.len(),
        m.failed.len(),
        if absent.is_empty() {
            String::new()
        } else {
            format!("; no output for shard(s) {}", absent.join(", "))
        }
    );
    for (id, names) in &m.duplicated {
        eprintln!(
            "duplicated: {id} is in {} (same results; kept once)",
            names.join(", ")
        );
    }
    for (id, why) in &m.failed {
        eprintln!("failed: {id}: {why}");
    }
    for id in &m.missing {
        eprintln!("missing: {id}");
    }
    if let Some(path) = &a.json {
        crate::io::output::write(
            path,
            OutputKind::RunJson,
            a.force,
            &crate::report::run_output_bytes(&m.file)?,
        )?;
        eprintln!("wrote {}", path.display());
    }
    if !m.missing.is_empty() && !a.allow_missing {
        return Err(Error::Missing(format!(
            "{} of {} pairs missing (listed above): run the missing shards again (they resume) \
             or pass --allow-missing",
            m.missing.len(),
            m.file.run.identity.selected.len()
        )));
    }
    Ok(())
}

/// The paths of `files`, comma-separated.
fn names(files: &[(PathBuf, String)]) -> String {
    files
        .iter()
        .map(|(p, _)| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

fn no_outputs(paths: &[PathBuf]) -> Error {
    Error::Missing(format!(
        "no shard outputs found in {}",
        paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    ))
}

/// The shard outputs under `paths` (folders: `*.json` in them and in their `shards/`), and
/// the files that should be shard outputs but cannot be read, with why. A file given by name
/// and every file in a `shards/` folder must be a run file; other JSON at a run folder's top
/// (the plan, a merged output) is skipped.
#[allow(clippy::type_complexity)]
fn collect(paths: &[PathBuf]) -> Result<(Vec<(PathBuf, RunFile)>, Vec<(PathBuf, String)>)> {
    // (path, whether it must be a shard output)
    let mut files: Vec<(PathBuf, bool)> = Vec::new();
    for p in paths {
        if p.is_dir() {
            for (d, strict) in [(p.clone(), false), (p.join("shards"), true)] {
                let Ok(rd) = std::fs::read_dir(&d) else {
                    continue;
                };
                let mut v: Vec<PathBuf> = rd
                    .flatten()
                    .map(|e| e.path())
                    .filter(|q| {
                        q.extension().is_some_and(|e| e == "json")
                            && !q
                                .file_name()
                                .is_some_and(|n| n.to_string_lossy().starts_with('.'))
                    })
                    .collect();
                v.sort();
                files.extend(v.into_iter().map(|q| (q, strict)));
            }
        } else if std::fs::symlink_metadata(p).is_err() {
            return Err(Error::Missing(format!(
                "{}: no such file or folder",
                p.display()
            )));
        } else {
            files.push((p.clone(), true));
        }
    }
    let mut out = Vec::new();
    let mut corrupt = Vec::new();
    for (f, strict) in files {
        match read_run_file(&f) {
            Ok(r) if r.run.merged_from.is_empty() => out.push((f, r)),
            // a merged output is not a shard output (merging it again would count twice)
            Ok(_) => {}
            Err(e) => {
                // Other JSON at a run folder's top (the plan) is not a shard output.
                let other_json = !strict
                    && matches!(
                        crate::io::output::read_json::<serde_json::Value>(&f, "JSON"),
                        Ok(serde_json::Value::Object(m)) if !m.contains_key("run")
                    );
                if !other_json {
                    corrupt.push((f, e.to_string()));
                }
            }
        }
    }
    Ok((out, corrupt))
}

/// The shard index a `cgenreg slurm` shard file name gives (`shard-I.json`).
fn index_from_name(p: &Path) -> Option<usize> {
    p.file_name()?
        .to_str()?
        .strip_prefix("shard-")?
        .strip_suffix(".json")?
        .parse()
        .ok()
}

/// A task's recorded exit status (`logs/task-I.rc`): a few bytes of a regular file, never
/// more (a link to a device reads as unknown).
fn read_rc(p: &Path) -> Option<String> {
    use std::io::Read;
    if !std::fs::metadata(p).ok()?.is_file() {
        return None;
    }
    let mut s = String::new();
    std::fs::File::open(p)
        .ok()?
        .take(32)
        .read_to_string(&mut s)
        .ok()?;
    let s = s.trim();
    (!s.is_empty() && s.chars().all(|c| c.is_ascii_digit() || c == '-')).then(|| s.to_string())
}

fn ago(unix: u64) -> String {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let s = now.saturating_sub(unix);
    if s < 120 {
        format!("{s} s ago")
    } else if s < 7200 {
        format!("{} min ago", s / 60)
    } else {
        format!("{:.1} h ago", s as f64 / 3600.0)
    }
}

pub fn run_status(a: StatusArgs) -> Result<()> {
    let (files, corrupt) = collect(&a.paths)?;
    let corrupt_error = || {
        Error::Invalid(format!(
            "{} run file(s) cannot be read: {}. Remove them, then run their shards again (a \
             shard without output starts over)",
            corrupt.len(),
            names(&corrupt)
        ))
    };
    if files.is_empty() {
        for (p, why) in &corrupt {
            outln!("corrupt: {}: {why}", p.display());
        }
        return Err(if corrupt.is_empty() {
            no_outputs(&a.paths)
        } else {
            corrupt_error()
        });
    }
    let first = &files[0].1.run.identity;
    let count = first.shard_count;
    let n_sel = first.selected.len();
    outln!(
        "{} of {} ({} pairs selected, {count} shards, {})",
        first.command,
        first.manifest,
        n_sel,
        first.code_version
    );
    // A `cgenreg slurm` run folder also has each task's exit status.
    let rc_of = |i: usize| -> String {
        a.paths
            .iter()
            .filter(|p| p.is_dir())
            .find_map(|p| read_rc(&p.join("logs").join(format!("task-{i}.rc"))))
            .unwrap_or_else(|| "-".into())
    };
    outln!("| shard | file | pairs | done | failed | missing | in flight | updated | exit |");
    outln!("|---|---|---|---|---|---|---|---|---|");
    let mut seen = vec![false; count];
    for (path, why) in &corrupt {
        let shard = match index_from_name(path).filter(|&i| i < count) {
            Some(i) => {
                seen[i] = true;
                format!("{i}/{count}")
            }
            None => "?".into(),
        };
        outln!(
            "| {shard} | {} | CORRUPT: {} | | | | | | |",
            path.display(),
            why.replace('|', "/").replace('\n', " ")
        );
    }
    let mut all: Vec<&PairRecord> = Vec::new();
    // per shard: pairs left and the mean time of its pairs done, for the time left
    let mut left: Vec<(usize, Option<f64>)> = vec![(0, None); count];
    for (path, f) in &files {
        let d = f.run.identity.differences(first);
        if !d.is_empty() {
            outln!(
                "| - | {} | another run: {} | | | | | | |",
                path.display(),
                d.join("; ")
            );
            continue;
        }
        let s = f.run.shard;
        if s.index < count {
            seen[s.index] = true;
        }
        let n = s.positions(n_sel).len();
        let failed = f.records.iter().filter(|r| r.status == FAILED).count();
        let done = f.records.len() - failed;
        if s.index < count {
            left[s.index] = (n.saturating_sub(done), mean_time(&f.records));
        }
        outln!(
            "| {s} | {} | {n} | {done} | {failed} | {} | {} | {} | {} |",
            path.display(),
            n.saturating_sub(f.records.len()),
            f.run.in_flight.as_deref().unwrap_or("-"),
            ago(f.run.updated_unix),
            rc_of(s.index)
        );
        all.extend(f.records.iter());
    }
    for (i, s) in seen.iter().enumerate() {
        if !s {
            let n = crate::pipeline::shard::Shard { index: i, count }
                .positions(n_sel)
                .len();
            outln!(
                "| {i}/{count} | (no output yet) | {n} | 0 | 0 | {n} | - | - | {} |",
                rc_of(i)
            );
            left[i] = (n, None);
        }
    }
    let failed = all.iter().filter(|r| r.status == FAILED).count();
    outln!(
        "\nin all: {} done, {failed} failed, {} missing of {n_sel}",
        all.len() - failed,
        n_sel.saturating_sub(all.len())
    );
    for r in all.iter().filter(|r| r.status == FAILED) {
        outln!("failed: {}: {}", r.id, r.error.as_deref().unwrap_or(""));
    }
    if let Some(line) = time_left(&left, mean_time(all.iter().copied())) {
        outln!("{line}");
    }
    print_cost(&all, a.project_pairs, backend_kind(&first.params));
    if !corrupt.is_empty() {
        return Err(corrupt_error());
    }
    Ok(())
}

/// The mean time of the pairs done (failed pairs excluded: they often end early).
fn mean_time<'a>(records: impl IntoIterator<Item = &'a PairRecord>) -> Option<f64> {
    let t: Vec<f64> = records
        .into_iter()
        .filter(|r| r.status != FAILED)
        .map(|r| r.time_s)
        .collect();
    (!t.is_empty()).then(|| t.iter().sum::<f64>() / t.len() as f64)
}

/// The time a run has left: each shard's pairs left (failed ones run again) at that shard's
/// measured time per pair (the run's mean where a shard has none yet). The shards of an
/// array run side by side, so the wall time is the slowest shard's; the work is their sum.
fn time_left(left: &[(usize, Option<f64>)], overall: Option<f64>) -> Option<String> {
    let pairs: usize = left.iter().map(|(n, _)| n).sum();
    if pairs == 0 {
        return Some("time left: none, every pair is done".into());
    }
    let secs: Vec<f64> = left
        .iter()
        .map(|&(n, t)| t.or(overall).map(|t| n as f64 * t))
        .collect::<Option<_>>()?;
    let work: f64 = secs.iter().sum();
    let wall = secs.iter().copied().fold(0.0, f64::max);
    let h = |s: f64| {
        if s < 5400.0 {
            format!("{:.0} min", s / 60.0)
        } else {
            format!("{:.1} h", s / 3600.0)
        }
    };
    Some(format!(
        "time left: {pairs} pairs at the measured time per pair: about {} with the {} shards \
         running side by side ({} of work on one worker)",
        h(wall),
        left.len(),
        h(work)
    ))
}

/// The image branch's generator (`WfmSpec`'s `kind`) recorded in a run's parameters, if any.
fn backend_kind(params: &serde_json::Value) -> Option<String> {
    match params {
        serde_json::Value::Object(m) => m
            .get("backend")
            .and_then(|b| b.get("kind"))
            .and_then(|k| k.as_str())
            .map(str::to_string)
            .or_else(|| m.values().find_map(backend_kind)),
        _ => None,
    }
}

/// Stage times and the projected cost of `project` pairs from the measured ones. Generation
/// is called GPU time only for Cosmos; the built-in generator runs on the CPU.
fn print_cost(records: &[&PairRecord], project: usize, backend: Option<String>) {
    let done: Vec<&PairRecord> = records
        .iter()
        .copied()
        .filter(|r| r.status != FAILED)
        .collect();
    if done.is_empty() {
        return;
    }
    outln!("\n| stage | pairs computed | mean s computed | pairs cached | mean s cached |");
    outln!("|---|---|---|---|---|");
    let mut computed_ms = vec![];
    for (stage, _, _, _) in stage_totals(done.iter().copied()) {
        let (mut c, mut cs, mut h, mut hs) = (0usize, 0.0, 0usize, 0.0);
        for r in &done {
            for s in r.stages.iter().filter(|s| s.stage == stage) {
                if crate::pipeline::result::is_cached(&s.status) {
                    h += 1;
                    hs += s.ms;
                } else {
                    c += 1;
                    cs += s.ms;
                }
            }
        }
        let mean = |t: f64, n: usize| {
            if n == 0 {
                "-".to_string()
            } else {
                format!("{:.3}", t / 1e3 / n as f64)
            }
        };
        outln!(
            "| {stage} | {c} | {} | {h} | {} |",
            mean(cs, c),
            mean(hs, h)
        );
        if c > 0 {
            computed_ms.push((stage, cs / c as f64));
        }
    }
    let per_pair = done.iter().map(|r| r.time_s).sum::<f64>() / done.len() as f64;
    outln!(
        "\nmeasured: {:.2} s per pair over {} pairs; {project} pairs at that rate: {:.2} h on one \
         worker",
        per_pair,
        done.len(),
        per_pair * project as f64 / 3600.0
    );
    if let Some((_, gen_ms)) = computed_ms.iter().find(|(s, _)| s == "generation") {
        let backend = backend.unwrap_or_else(|| "unknown".into());
        let unit = if backend == "cosmos" {
            "GPU-hours for generation alone (one GPU per task; divide by the array size for the \
             wall time)"
                .to_string()
        } else {
            format!(
                "hours of generation on one worker ({backend} generator: not a GPU figure; \
                 Cosmos-Transfer1 is about 507 s per pair on an RTX A6000 in the paper)"
            )
        };
        outln!(
            "generation (computed, not cached, {backend}): {:.2} s per pair, so {project} pairs \
             need {:.2} {unit}",
            gen_ms / 1e3,
            gen_ms / 1e3 * project as f64 / 3600.0
        );
    }
}

/// Used by `slurm` to find the shard file names.
pub fn shard_path(out: &Path, index: usize) -> PathBuf {
    out.join("shards").join(format!("shard-{index}.json"))
}

#[cfg(test)]
mod tests {
    use super::time_left;

    /// The wall time is the slowest shard's (its own rate, else the run's); the work their sum.
    #[test]
    fn time_left_takes_the_slowest_shard() {
        let line = time_left(&[(10, Some(6.0)), (20, None)], Some(3.0)).unwrap();
        // shard 0: 60 s, shard 1: 20 x 3 s = 60 s; work 120 s
        assert!(line.contains("30 pairs"), "{line}");
        assert!(line.contains("about 1 min with the 2 shards"), "{line}");
        assert!(line.contains("(2 min of work"), "{line}");
        let line = time_left(&[(3000, Some(6.0)), (0, Some(1.0))], None).unwrap();
        assert!(line.contains("about 5.0 h"), "{line}");
        assert_eq!(
            time_left(&[(0, None), (0, Some(2.0))], None).as_deref(),
            Some("time left: none, every pair is done")
        );
        // nothing measured yet: no projection
        assert_eq!(time_left(&[(5, None)], None), None);
    }
}
