//! `cgenreg slurm` on a REAL single-node Slurm (munged + slurmctld + slurmd from the Debian
//! packages, started here by scripts/slurm-local.sh in a temporary folder on free ports, and
//! stopped at the end): a 3-task array benches staged pairs with the built-in generator and one
//! shared cache, the merge step (afterok) runs, and its result equals a local unsharded bench
//! pair by pair; then one array task is killed mid-run (scancel) and resubmitting the same plan
//! finishes only its missing pair.
//!
//! When Slurm cannot start (packages missing, not root), the test fails under CI=true with the
//! reason and is skipped with the reason elsewhere.

use crate::common;

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const WAIT: Duration = Duration::from_secs(240);

struct Slurm {
    dir: PathBuf,
    conf: PathBuf,
}

impl Drop for Slurm {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(script())
            .arg("stop")
            .arg(&self.dir)
            .status();
    }
}

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm-local.sh")
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn start_slurm(dir: &Path) -> Result<Slurm, String> {
    let o = Command::new("bash")
        .arg(script())
        .arg("start")
        .arg(dir)
        .env("CGENREG_SLURM_CTLD_PORT", free_port().to_string())
        .env("CGENREG_SLURM_D_PORT", free_port().to_string())
        .output()
        .map_err(|e| format!("could not run {}: {e}", script().display()))?;
    let slurm = Slurm {
        dir: dir.to_path_buf(),
        conf: dir.join("slurm.conf"),
    };
    if !o.status.success() {
        return Err(String::from_utf8_lossy(&o.stderr).trim().to_string());
    }
    Ok(slurm)
}

fn cgenreg(s: &Slurm) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cgenreg"));
    c.env("SLURM_CONF", &s.conf).env_remove("CGENREG_CACHE");
    c
}

fn slurm_cmd(s: &Slurm, prog: &str) -> Command {
    let mut c = Command::new(prog);
    c.env("SLURM_CONF", &s.conf);
    c
}

fn ok(c: &mut Command) -> Output {
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "{c:?}: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn read(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
        .unwrap()
}

fn results(v: &Value) -> Vec<Value> {
    v["records"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            serde_json::json!({
                "id": r["id"], "status": r["status"],
                "result": cgenreg::pipeline::shard::strip_times(&r["result"]),
            })
        })
        .collect()
}

/// Waits until none of `jobs` is in the queue any more.
fn wait_jobs(s: &Slurm, jobs: &[&str], log: &Path) {
    let t = Instant::now();
    loop {
        let o = ok(slurm_cmd(s, "squeue").args(["-h", "-o", "%i %T %r", "-j", &jobs.join(",")]));
        let q = String::from_utf8_lossy(&o.stdout).trim().to_string();
        if q.is_empty() {
            return;
        }
        if t.elapsed() > WAIT {
            let logs = std::fs::read_to_string(log).unwrap_or_default();
            panic!("jobs {jobs:?} still queued after {WAIT:?}: {q}\n{logs}");
        }
        std::thread::sleep(Duration::from_millis(300));
    }
}

/// "submitted array job 12 ..." / "submitted merge job 13 ...".
fn job_ids(stdout: &str) -> (String, String) {
    let id = |what: &str| {
        stdout
            .lines()
            .find_map(|l| l.strip_prefix(&format!("submitted {what} job ")))
            .and_then(|r| r.split_whitespace().next())
            .unwrap_or_else(|| panic!("no {what} job id in: {stdout}"))
            .to_string()
    };
    (id("array"), id("merge"))
}

fn tail(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| format!("({}: {e})", p.display()))
}

#[test]
fn a_job_array_on_a_real_slurm_merges_to_the_local_run_and_a_killed_task_resumes() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let slurm = match start_slurm(&tmp.path().join("slurm")) {
        Ok(s) => s,
        Err(why) if std::env::var("CI").as_deref() == Ok("true") => {
            panic!("CI=true but a local Slurm could not start: {why}")
        }
        Err(why) => {
            eprintln!("skipped: a local Slurm could not start: {why}");
            return;
        }
    };
    eprintln!("slurm up in {:.1} s", t0.elapsed().as_secs_f64());
    let manifest =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-staged.toml");
    // Four staged pairs, the built-in generator (NOT a WFM) on L = 8 frames, keypoints on a
    // 10 cm grid (what is compared does not depend on their number), one shared cache.
    let opts = |cache: &Path| -> Vec<String> {
        let mut v: Vec<String> = [
            "--voxel",
            "0.1",
            "--limit",
            "4",
            "--wfm",
            "builtin",
            "--frames",
            "8",
            "--margin",
            "1",
            "--k",
            "2",
            "--cache-dir",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        v.push(cache.display().to_string());
        v
    };
    let submit = |out: &Path, cache: &Path| -> (String, String) {
        let o = ok(cgenreg(&slurm)
            .env("CGENREG_DATA", &data)
            .arg("slurm")
            .arg("bench")
            .arg(&manifest)
            .args(["--array", "3", "--cpus-per-task", "1", "--time", "00:10:00"])
            .arg("--out")
            .arg(out)
            .arg("--submit")
            .arg("--")
            .args(opts(cache)));
        let s = String::from_utf8_lossy(&o.stdout).to_string();
        eprint!("{s}{}", String::from_utf8_lossy(&o.stderr));
        job_ids(&s)
    };

    // 1. The array of 3 and its merge step.
    let cache = tmp.path().join("cache");
    let out = tmp.path().join("run1");
    let t = Instant::now();
    let (jid, mid) = submit(&out, &cache);
    wait_jobs(&slurm, &[&jid, &mid], &out.join("logs/task-0.log"));
    eprintln!(
        "array {jid} + merge {mid} done in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    for i in 0..3 {
        let log = out.join(format!("logs/task-{i}.log"));
        let rc = std::fs::read_to_string(out.join(format!("logs/task-{i}.rc"))).unwrap_or_default();
        assert_eq!(rc.trim(), "0", "task {i}: {}", tail(&log));
        eprintln!("--- task {i} log:\n{}", tail(&log));
    }
    eprintln!("--- merge log:\n{}", tail(&out.join("logs/merge.log")));
    let merged = read(&out.join("merged.json"));
    assert_eq!(merged["run"]["complete"], true);

    // The same bench locally, unsharded, on the same cache.
    let local = tmp.path().join("local.json");
    ok(cgenreg(&slurm)
        .env("CGENREG_DATA", &data)
        .arg("bench")
        .arg(&manifest)
        .args(opts(&cache))
        .arg("--json")
        .arg(&local));
    let (rl, rm) = (results(&read(&local)), results(&merged));
    assert_eq!(rl.len(), 4);
    assert_eq!(rl.len(), rm.len());
    for (a, b) in rl.iter().zip(&rm) {
        assert!(
            common::json_close(a, b),
            "pair {} differs between the local run and the merged array:\n{a}\n{b}",
            a["id"]
        );
        eprintln!(
            "{}: {} {}",
            if a == b { "equal" } else { "equal to 1e-12" },
            a["id"],
            a["result"]["rre_deg"]
        );
    }
    assert!(common::json_close(
        &cgenreg::pipeline::shard::strip_times(&read(&local)["summary"]),
        &cgenreg::pipeline::shard::strip_times(&merged["summary"])
    ));
    eprintln!("merged array == local unsharded bench: 4 pairs, summary equal");

    // 2. Kill task 0 (pairs 0 and 3) after its first pair (a fresh cache, so every pair
    //    computes), then resubmit the same plan: only task 0's second pair runs.
    let cache2 = tmp.path().join("cache2");
    let out2 = tmp.path().join("run2");
    let (jid2, mid2) = submit(&out2, &cache2);
    let shard0 = out2.join("shards/shard-0.json");
    let t = Instant::now();
    loop {
        let n = std::fs::read(&shard0)
            .ok()
            .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
            .map(|v| {
                (
                    v["records"].as_array().map_or(0, |a| a.len()),
                    v["run"]["in_flight"].clone(),
                )
            });
        match n {
            Some((1, f)) if f.is_string() => break,
            Some((n, _)) if n >= 2 => panic!("shard 0 finished before it could be killed"),
            _ => {}
        }
        assert!(
            t.elapsed() < WAIT,
            "shard 0 never started: {}",
            tail(&out2.join("logs/task-0.log"))
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    ok(slurm_cmd(&slurm, "scancel").arg(format!("{jid2}_0")));
    eprintln!("scancel {jid2}_0 after its first pair");
    // The merge step can never run now (afterok): cancel it too.
    let _ = slurm_cmd(&slurm, "scancel").arg(&mid2).status();
    wait_jobs(&slurm, &[&jid2, &mid2], &out2.join("logs/task-0.log"));
    let st = ok(cgenreg(&slurm).arg("status").arg(&out2));
    let st = String::from_utf8_lossy(&st.stdout).to_string();
    eprintln!("--- status after the kill:\n{st}");
    assert!(
        st.contains("in all: 3 done, 0 failed, 1 missing of 4"),
        "{st}"
    );
    assert!(
        !out2.join("logs/task-0.rc").exists(),
        "a killed task wrote an exit status"
    );

    let (jid3, mid3) = submit(&out2, &cache2);
    wait_jobs(&slurm, &[&jid3, &mid3], &out2.join("logs/task-0.log"));
    let log1 = tail(&out2.join("logs/task-0.log"));
    eprintln!("--- task 0 log (killed run, then the resubmission):\n{log1}");
    let resumed = log1
        .split("resuming")
        .nth(1)
        .unwrap_or_else(|| panic!("task 0 did not resume: {log1}"));
    assert!(
        resumed.contains("1 of 2 pairs of shard 0/3 done, 1 to run"),
        "{log1}"
    );
    assert_eq!(resumed.matches("[shard 0/3]").count(), 1, "{log1}");
    for i in [1, 2] {
        let l = tail(&out2.join(format!("logs/task-{i}.log")));
        let r = l.split("resuming").nth(1).unwrap_or_else(|| panic!("{l}"));
        assert!(
            r.contains(&format!("1 of 1 pairs of shard {i}/3 done, 0 to run")),
            "{l}"
        );
        assert_eq!(
            r.matches(&format!("[shard {i}/3]")).count(),
            0,
            "task {i} ran pairs again: {l}"
        );
    }
    let merged2 = read(&out2.join("merged.json"));
    let r2 = Value::Array(results(&merged2));
    assert!(
        common::json_close(&r2, &Value::Array(rl.clone())),
        "the resumed run differs from the local run"
    );
    eprintln!(
        "resubmitted: only the killed task's missing pair ran; merged == local; {:.1} s in all",
        t0.elapsed().as_secs_f64()
    );
    drop(slurm);
}
