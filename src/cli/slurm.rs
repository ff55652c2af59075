//! `cgenreg slurm bench|generate|study-k|study-prompt`: a run as a Slurm job array, and the
//! hidden `cgenreg slurm-task DIR` that each array task runs.
//!
//! `cgenreg slurm bench M --array N --out DIR [slurm options] [--submit] -- [bench options]`
//! writes into DIR:
//! - `plan.json`: the command, the manifest, the options after `--` (an argument vector, never
//!   a shell string), N and the binary;
//! - `array.sbatch`: a job array of N tasks; task i runs `cgenreg slurm-task DIR`, which runs
//!   shard i/N of the command with `--json DIR/shards/shard-i.json`, logs to
//!   `DIR/logs/task-i.log` (appended, so a resubmission keeps the killed run's lines) and
//!   records its exit status in `DIR/logs/task-i.rc`;
//! - `merge.sbatch`: `cgenreg merge DIR --json DIR/merged.json`, to be submitted with
//!   `--dependency=afterok:<array job>`.
//!
//! With `--submit` both are submitted with `sbatch` (run with an argument vector) and the job
//! ids printed. Resubmitting the same plan resumes: finished shards exit at once, a killed
//! shard runs only its missing pairs. The scripts contain no user text but validated paths and
//! validated Slurm option values.

use crate::error::{Error, Result};
use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SlurmCommand {
    Bench,
    Generate,
    StudyK,
    StudyPrompt,
}

impl SlurmCommand {
    /// The cgenreg arguments that start the command.
    fn argv(&self) -> Vec<&'static str> {
        match self {
            SlurmCommand::Bench => vec!["bench"],
            SlurmCommand::Generate => vec!["generate"],
            SlurmCommand::StudyK => vec!["study", "k"],
            SlurmCommand::StudyPrompt => vec!["study", "prompt"],
        }
    }
}

#[derive(Args, Debug)]
pub struct SlurmArgs {
    /// What each array task runs.
    #[arg(value_enum)]
    pub command: SlurmCommand,
    /// Dataset manifest (TOML); use a path every node can read.
    pub manifest: PathBuf,
    /// Number of array tasks (= shards).
    #[arg(long)]
    pub array: usize,
    /// Run folder on the shared file system (plan, scripts, shard outputs, logs).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long)]
    pub partition: Option<String>,
    /// e.g. gpu:1.
    #[arg(long)]
    pub gres: Option<String>,
    /// Time limit per task, e.g. 04:00:00.
    #[arg(long)]
    pub time: Option<String>,
    #[arg(long)]
    pub cpus_per_task: Option<usize>,
    /// Memory per task, e.g. 16G.
    #[arg(long)]
    pub mem: Option<String>,
    #[arg(long)]
    pub account: Option<String>,
    /// At most this many tasks at once (`--array=0-(N-1)%K`).
    #[arg(long)]
    pub max_running: Option<usize>,
    /// Submit the array and the merge step (afterok) with sbatch and print the job ids.
    #[arg(long)]
    pub submit: bool,
    /// Options of the command itself (after `--`), passed to every task as they are.
    #[arg(last = true, allow_hyphen_values = true)]
    pub args: Vec<String>,
}

/// What every task runs (`plan.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub command: SlurmCommand,
    pub manifest: PathBuf,
    pub args: Vec<String>,
    pub array: usize,
    pub binary: PathBuf,
}

pub const PLAN: &str = "plan.json";

fn shard_json(out: &Path, i: usize) -> PathBuf {
    super::merge::shard_path(out, i)
}

/// Paths in the scripts and `#SBATCH` lines must need no quoting there.
fn plain_path(what: &str, p: &Path) -> Result<String> {
    let s = p.to_string_lossy().into_owned();
    let ok = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+,:@".contains(c));
    if ok {
        Ok(s)
    } else {
        Err(Error::Param(format!(
            "{what} {s:?}: use a path of letters, digits and / . _ - + , : @ only (it goes into \
             #SBATCH lines, which are not shell-quoted)"
        )))
    }
}

/// A Slurm option value: letters, digits and `_ . : , = / - + @` only.
fn plain_value(what: &str, v: &str) -> Result<String> {
    if !v.is_empty()
        && v.chars()
            .all(|c| c.is_ascii_alphanumeric() || "_.:,=/-+@".contains(c))
    {
        Ok(v.to_string())
    } else {
        Err(Error::Param(format!(
            "--{what} {v:?}: letters, digits and _ . : , = / - + @ only"
        )))
    }
}

/// A path that goes into a script (a comment or a quoted argument) must not end a line:
/// newlines, carriage returns, NUL and the other control characters are refused.
fn no_control_chars(what: &str, p: &Path) -> Result<String> {
    let s = p.to_string_lossy().into_owned();
    if let Some(c) = s.chars().find(|c| c.is_control()) {
        return Err(Error::Param(format!(
            "{what} {s:?}: contains the control character {c:?}; paths that go into the job \
             scripts cannot hold newlines, carriage returns or other control characters \
             (rename the folder)"
        )));
    }
    Ok(s)
}

/// `s` as one shell word: single-quoted, with each `'` written as `'\''`.
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

fn absolute(p: &Path) -> Result<PathBuf> {
    if p.is_absolute() {
        Ok(p.to_path_buf())
    } else {
        let cwd = std::env::current_dir().map_err(|e| Error::io(".", e))?;
        Ok(cwd.join(p))
    }
}

/// The argument vector of shard `index` of `plan` (without the program).
pub fn task_argv(plan: &Plan, out: &Path, index: usize) -> Vec<String> {
    let mut v: Vec<String> = plan.command.argv().iter().map(|s| s.to_string()).collect();
    v.push(plan.manifest.display().to_string());
    v.push("--shard".into());
    v.push(format!("{index}/{}", plan.array));
    v.push("--json".into());
    v.push(shard_json(out, index).display().to_string());
    v.extend(plan.args.iter().cloned());
    v
}

pub fn run(a: SlurmArgs) -> Result<()> {
    if a.array == 0 {
        return Err(Error::Param("--array must be at least 1".into()));
    }
    let out = absolute(&a.out)?;
    let out_s = plain_path("--out", &out)?;
    let manifest = absolute(&a.manifest)?;
    let manifest_s = no_control_chars("the manifest path", &manifest)?;
    if !manifest.is_file() {
        return Err(Error::Missing(format!(
            "{}: no such manifest",
            manifest.display()
        )));
    }
    let binary = std::env::current_exe().map_err(|e| Error::io("the running executable", e))?;
    let bin_s = plain_path("the cgenreg binary", &binary)?;
    let plan = Plan {
        command: a.command,
        manifest: manifest.clone(),
        args: a.args.clone(),
        array: a.array,
        binary: binary.clone(),
    };
    // Check the task command line now, not on the cluster.
    let mut argv = vec!["cgenreg".to_string()];
    argv.extend(task_argv(&plan, &out, 0));
    if let Err(e) = <super::Cli as clap::Parser>::try_parse_from(&argv) {
        return Err(Error::Invalid(format!(
            "the task command line would not parse: {e}"
        )));
    }
    for d in ["shards", "logs"] {
        let p = out.join(d);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
    }
    let plan_path = out.join(PLAN);
    if std::fs::symlink_metadata(&plan_path).is_ok() {
        let old: Plan = crate::io::output::read_json(&plan_path, "cgenreg slurm plan")?;
        if old != plan {
            return Err(Error::Usage(format!(
                "{} holds another plan (old: {} {} --array {} -- {:?}); use another --out, \
                 or remove the folder to start over",
                plan_path.display(),
                old.command.argv().join(" "),
                old.manifest.display(),
                old.array,
                old.args
            )));
        }
        eprintln!(
            "{} has this plan already: shards resume from their outputs",
            out.display()
        );
    }
    let pj = serde_json::to_vec_pretty(&plan)
        .map_err(|e| Error::Encode(format!("serialising the plan: {e}")))?;
    crate::io::output::write_atomic(&plan_path, &pj)?;

    let mut sbatch = String::from("#!/bin/bash\n");
    let name = format!("cgenreg-{}", plan.command.argv().join("-"));
    sbatch.push_str(&format!("#SBATCH --job-name={name}\n"));
    let range = match a.max_running {
        Some(k) => format!("0-{}%{k}", a.array - 1),
        None => format!("0-{}", a.array - 1),
    };
    sbatch.push_str(&format!("#SBATCH --array={range}\n"));
    sbatch.push_str(&format!("#SBATCH --output={out_s}/logs/task-%a.log\n"));
    sbatch.push_str("#SBATCH --open-mode=append\n");
    let mut opts: Vec<(&str, String)> = Vec::new();
    if let Some(p) = &a.partition {
        opts.push(("partition", plain_value("partition", p)?));
    }
    if let Some(g) = &a.gres {
        opts.push(("gres", plain_value("gres", g)?));
    }
    if let Some(t) = &a.time {
        opts.push(("time", plain_value("time", t)?));
    }
    if let Some(c) = a.cpus_per_task {
        opts.push(("cpus-per-task", c.to_string()));
    }
    if let Some(m) = &a.mem {
        opts.push(("mem", plain_value("mem", m)?));
    }
    if let Some(acc) = &a.account {
        opts.push(("account", plain_value("account", acc)?));
    }
    for (k, v) in &opts {
        sbatch.push_str(&format!("#SBATCH --{k}={v}\n"));
    }
    // Every value below is a validated path without control characters, and shell-quoted:
    // nothing can end the comment line or run as a command.
    sbatch.push_str(&format!(
        "# Task i runs shard i/{n} of: cgenreg {cmd} {m} --shard i/{n} --json {sh_out}/shards/shard-i.json \
         (+ the options in plan.json).\n\
         # The options travel in plan.json, never through this script.\n\
         exec {sh_bin} slurm-task {sh_out}\n",
        n = a.array,
        cmd = plan.command.argv().join(" "),
        m = sh_quote(&manifest_s),
        sh_out = sh_quote(&out_s),
        sh_bin = sh_quote(&bin_s),
    ));
    let array_path = out.join("array.sbatch");
    crate::io::output::write_atomic(&array_path, sbatch.as_bytes())?;

    let mut merge = String::from("#!/bin/bash\n");
    merge.push_str("#SBATCH --job-name=cgenreg-merge\n");
    merge.push_str(&format!("#SBATCH --output={out_s}/logs/merge.log\n"));
    merge.push_str("#SBATCH --open-mode=append\n");
    for (k, v) in opts
        .iter()
        .filter(|(k, _)| matches!(*k, "partition" | "account"))
    {
        merge.push_str(&format!("#SBATCH --{k}={v}\n"));
    }
    merge.push_str(&format!(
        "exec {} merge {} --json {}\n",
        sh_quote(&bin_s),
        sh_quote(&format!("{out_s}/shards")),
        sh_quote(&format!("{out_s}/merged.json"))
    ));
    let merge_path = out.join("merge.sbatch");
    crate::io::output::write_atomic(&merge_path, merge.as_bytes())?;
    outln!("wrote {} ({} tasks)", array_path.display(), a.array);
    outln!("wrote {}", merge_path.display());

    if !a.submit {
        outln!("submit with:");
        outln!("  jid=$(sbatch --parsable {})", array_path.display());
        outln!(
            "  sbatch --dependency=afterok:$jid {}",
            merge_path.display()
        );
        outln!("follow with: cgenreg status {}", out.display());
        return Ok(());
    }
    let jid = sbatch_submit(&[array_path.display().to_string()])?;
    outln!("submitted array job {jid} ({} tasks)", a.array);
    let mid = sbatch_submit(&[
        format!("--dependency=afterok:{jid}"),
        merge_path.display().to_string(),
    ])?;
    outln!("submitted merge job {mid} (after the array succeeds)");
    crate::io::output::write_atomic(
        &out.join("jobs.txt"),
        format!("array {jid}\nmerge {mid}\n").as_bytes(),
    )?;
    Ok(())
}

/// `sbatch --parsable ARGS...`: the job id.
fn sbatch_submit(args: &[String]) -> Result<String> {
    let o = Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .output()
        .map_err(|e| Error::External {
            what: "sbatch".into(),
            message: format!("could not run sbatch: {e} (is Slurm installed and SLURM_CONF set?)"),
        })?;
    if !o.status.success() {
        return Err(Error::External {
            what: "sbatch".into(),
            message: format!(
                "{}: {}",
                o.status,
                String::from_utf8_lossy(&o.stderr).trim()
            ),
        });
    }
    let s = String::from_utf8_lossy(&o.stdout);
    // --parsable prints "jobid" or "jobid;cluster".
    let id = s.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit() || c == '_') {
        return Err(Error::External {
            what: "sbatch".into(),
            message: format!("unexpected output {s:?}"),
        });
    }
    Ok(id)
}

#[derive(Args, Debug)]
pub struct SlurmTaskArgs {
    /// The run folder written by `cgenreg slurm`.
    pub dir: PathBuf,
    /// The shard to run; default $SLURM_ARRAY_TASK_ID.
    #[arg(long)]
    pub index: Option<usize>,
}

/// One array task: shard i of the plan in DIR, in this process; the exit status also goes to
/// `DIR/logs/task-i.rc`.
pub fn run_task(a: SlurmTaskArgs) -> Result<()> {
    let plan_path = a.dir.join(PLAN);
    let plan: Plan = crate::io::output::read_json(&plan_path, "cgenreg slurm plan")?;
    let index = match a.index {
        Some(i) => i,
        None => std::env::var("SLURM_ARRAY_TASK_ID")
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .ok_or_else(|| {
                Error::Missing("no --index and no SLURM_ARRAY_TASK_ID in the environment".into())
            })?,
    };
    if index >= plan.array {
        return Err(Error::Param(format!(
            "task {index} of an array of {}",
            plan.array
        )));
    }
    let mut argv = vec!["cgenreg".to_string()];
    argv.extend(task_argv(&plan, &a.dir, index));
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    eprintln!(
        "== task {index}/{} on {} (job {}), pid {}: {}",
        plan.array,
        host.trim(),
        std::env::var("SLURM_JOB_ID").unwrap_or_else(|_| "-".into()),
        std::process::id(),
        argv[1..].join(" ")
    );
    let t = std::time::Instant::now();
    let cli = <super::Cli as clap::Parser>::try_parse_from(&argv)
        .map_err(|e| Error::Invalid(format!("the task's command line: {e}")))?;
    let r = match cli.command {
        Some(c) => super::run_command(c),
        None => Err(Error::Missing("no command in the plan".into())),
    };
    let rc = if r.is_ok() { 0 } else { 1 };
    let rc_path = a.dir.join("logs").join(format!("task-{index}.rc"));
    let _ = crate::io::output::write_atomic(&rc_path, format!("{rc}\n").as_bytes());
    eprintln!(
        "== task {index}/{} finished with exit status {rc} after {:.1} s",
        plan.array,
        t.elapsed().as_secs_f64()
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn option_values_and_paths_are_checked() {
        assert!(plain_value("gres", "gpu:1").is_ok());
        assert!(plain_value("time", "04:00:00").is_ok());
        for bad in ["gpu:1\n#SBATCH --x", "a b", "$(rm)", "`x`", "'", ""] {
            assert!(plain_value("gres", bad).is_err(), "{bad:?}");
        }
        assert!(plain_path("x", Path::new("/scratch/run-1/a_b.c")).is_ok());
        for bad in ["/a b", "/a'b", "/a\nb", "/a%b", "/a$b"] {
            assert!(plain_path("x", Path::new(bad)).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn script_values_are_quoted_and_control_characters_refused() {
        assert_eq!(sh_quote("/a b/it's"), "'/a b/it'\\''s'");
        for bad in [
            "/d/x\ntouch /tmp/pwn\n/m.toml",
            "/d/x\r\n/m",
            "/d/\u{1b}x",
            "/d/\u{7f}",
        ] {
            let e = no_control_chars("the manifest path", Path::new(bad))
                .unwrap_err()
                .to_string();
            assert!(e.contains("control character"), "{e}");
        }
        assert!(no_control_chars("m", Path::new("/d/a b/$(x)/m.toml")).is_ok());
    }

    #[test]
    fn task_argv_carries_shard_json_and_options_verbatim() {
        let plan = Plan {
            command: SlurmCommand::StudyK,
            manifest: "/d/m.toml".into(),
            args: vec!["--prompt".into(), "a kitchen; rm -rf /".into()],
            array: 3,
            binary: "/b/cgenreg".into(),
        };
        let v = task_argv(&plan, Path::new("/out"), 2);
        assert_eq!(
            v,
            [
                "study",
                "k",
                "/d/m.toml",
                "--shard",
                "2/3",
                "--json",
                "/out/shards/shard-2.json",
                "--prompt",
                "a kitchen; rm -rf /"
            ]
        );
    }
}
