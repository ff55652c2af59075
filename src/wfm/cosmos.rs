//! The `cosmos` backend: writes the Cosmos-Transfer1 batch input exactly as the reference
//! (§2.3, §2.4), runs a user-configured command, and ingests `video_0/output.mp4`.
//!
//! Per request a fresh job folder `<work_dir>/<pair>-<unix>-<pid>-<n>/` holds:
//! - `input/depth.mp4`: the depth-control video (H.264, 30 fps), unless the request already
//!   has an mp4 (`depth_video_path`), which is then used where it is;
//! - `batch_input.jsonl`: one line `{"prompt", "control_overrides": {"depth":
//!   {"input_control", "control_weight"}}, "video_save_name": "0_gen_vid"}`;
//! - `controlnet_spec.json`: `{"prompt", "depth": {"input_control", "control_weight"}}`;
//! - `output/`: the `--video_save_folder`; Cosmos writes `output/video_0/{output.mp4,prompt.txt}`;
//! - `cosmos_stdout.log`, `cosmos_stderr.log`: everything the command printed.
//!
//! The command is an argument vector run without a shell. An argument that is exactly one of
//! `{batch_input_path}`, `{video_save_folder}`, `{controlnet_specs}`, `{depth_video}`,
//! `{seed}`, `{job_dir}` or `{checkpoint_dir}` is replaced by its value; other arguments pass
//! through untouched (so the prompt, which travels in the files, can never be re-parsed as
//! arguments). An argument that looks like an unknown `{placeholder}` is an error. The child
//! runs in its own process group with a unique `CGENREG_JOB_TOKEN` in its environment; when
//! it exits (successfully or not) or times out, the group and every process carrying the
//! token (e.g. a `setsid` grandchild) are killed, so nothing it started outlives the call.
//! Error messages quote the last 20 lines of the stderr log, read from its last 64 KiB.

use super::backend::{now_unix, sanitize, GenerateRequest, Generation, Provenance, WfmBackend};
use super::prompt::{to_ascii_json, BatchLine};
use super::video::{read_mp4_frames, write_mp4_h264};
use crate::error::{Error, Result};
use crate::io::output::write_atomic;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// Placeholders substituted as whole arguments.
pub const PLACEHOLDERS: [&str; 7] = [
    "{batch_input_path}",
    "{video_save_folder}",
    "{controlnet_specs}",
    "{depth_video}",
    "{seed}",
    "{job_dir}",
    "{checkpoint_dir}",
];

#[derive(Clone, Debug)]
pub struct CosmosConfig {
    /// Argument vector template; `command[0]` is the program.
    pub command: Vec<String>,
    /// Where job folders are created.
    pub work_dir: PathBuf,
    /// Working directory of the command (the reference runs from `$COSMOS_ROOT`).
    pub cwd: Option<PathBuf>,
    /// Extra environment variables (e.g. `PYTHONPATH=$COSMOS_ROOT`).
    pub env: Vec<(String, String)>,
    /// The child (and its process group) is killed after this long.
    pub timeout: Duration,
    /// `control_overrides.depth.control_weight` (1.0 in the reference).
    pub control_weight: f64,
    /// Value of `{checkpoint_dir}`.
    pub checkpoint_dir: Option<PathBuf>,
    /// The model name recorded in the provenance.
    pub model: String,
}

impl CosmosConfig {
    /// A config for an arbitrary command (tests, wrappers, remote submit scripts).
    pub fn new(command: Vec<String>, work_dir: impl Into<PathBuf>, timeout: Duration) -> Self {
        CosmosConfig {
            command,
            work_dir: work_dir.into(),
            cwd: None,
            env: Vec::new(),
            timeout,
            control_weight: 1.0,
            checkpoint_dir: None,
            model: "Cosmos-Transfer1-7B (depth control)".into(),
        }
    }

    /// The reference's invocation (§2.2): `torchrun ... transfer.py --sigma_max 80 --fps 30`,
    /// run from `cosmos_root` with `PYTHONPATH=cosmos_root`. Every other flag keeps the pinned
    /// `transfer.py` default, except `--seed`, which carries the request's seed.
    pub fn reference(
        cosmos_root: &Path,
        checkpoint_dir: &Path,
        num_gpu: usize,
        work_dir: impl Into<PathBuf>,
    ) -> Self {
        let n = num_gpu.max(1).to_string();
        let command = [
            "torchrun",
            &format!("--nproc_per_node={n}"),
            "--nnodes=1",
            "--node_rank=0",
            "cosmos_transfer1/diffusion/inference/transfer.py",
            "--checkpoint_dir",
            "{checkpoint_dir}",
            "--video_save_folder",
            "{video_save_folder}",
            "--controlnet_specs",
            "{controlnet_specs}",
            "--sigma_max",
            "80",
            "--fps",
            "30",
            "--num_gpus",
            &n,
            "--seed",
            "{seed}",
            "--batch_input_path",
            "{batch_input_path}",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let mut c = CosmosConfig::new(command, work_dir, Duration::from_secs(3 * 3600));
        c.cwd = Some(cosmos_root.to_path_buf());
        c.env = vec![(
            "PYTHONPATH".into(),
            cosmos_root.to_string_lossy().into_owned(),
        )];
        c.checkpoint_dir = Some(checkpoint_dir.to_path_buf());
        c
    }
}

pub struct CosmosBackend {
    pub config: CosmosConfig,
}

static JOB_COUNTER: AtomicUsize = AtomicUsize::new(0);

impl CosmosBackend {
    pub fn new(config: CosmosConfig) -> Result<Self> {
        if config.command.is_empty() {
            return Err(Error::Param(
                "cosmos backend: the command is empty; give the program and its arguments".into(),
            ));
        }
        for a in &config.command {
            if looks_like_placeholder(a) && !PLACEHOLDERS.contains(&a.as_str()) {
                return Err(Error::Param(format!(
                    "cosmos backend: unknown placeholder argument `{a}`; known: {}",
                    PLACEHOLDERS.join(" ")
                )));
            }
        }
        if !(config.control_weight.is_finite() && config.control_weight >= 0.0) {
            return Err(Error::Param(format!(
                "cosmos backend: control_weight must be a non-negative number, found {}",
                config.control_weight
            )));
        }
        Ok(CosmosBackend { config })
    }

    fn job_dir(&self, pair_id: &str) -> PathBuf {
        let n = JOB_COUNTER.fetch_add(1, Ordering::Relaxed);
        self.config.work_dir.join(format!(
            "{}-{}-{}-{n}",
            sanitize(pair_id),
            now_unix(),
            std::process::id()
        ))
    }
}

fn looks_like_placeholder(a: &str) -> bool {
    a.len() > 2
        && a.starts_with('{')
        && a.ends_with('}')
        && a[1..a.len() - 1]
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_')
}

fn abs(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).map_err(|e| Error::io(p, e))
}

/// Write the controlnet spec JSON (§2.3) for one depth video.
pub fn write_controlnet_spec(
    path: &Path,
    prompt: &str,
    depth_video: &Path,
    control_weight: f64,
) -> Result<()> {
    let v = serde_json::json!({
        "prompt": prompt,
        "depth": {
            "input_control": depth_video.to_string_lossy(),
            "control_weight": control_weight,
        }
    });
    write_atomic(path, to_ascii_json(&v).as_bytes())
}

/// Environment variable set to a unique token in the generator's environment; every
/// process it starts inherits it, so its whole tree can be found (and killed) even after a
/// grandchild left the process group with `setsid`.
pub const JOB_TOKEN_ENV: &str = "CGENREG_JOB_TOKEN";

/// A fresh token for one generator run.
fn job_token() -> String {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!(
        "{}-{nanos}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    )
}

/// Pids of live processes whose environment holds `JOB_TOKEN_ENV=token` (Linux `/proc`;
/// empty elsewhere). Zombies are skipped: they are already dead.
#[cfg(target_os = "linux")]
fn processes_with_token(token: &str) -> Vec<i32> {
    let needle = format!("{JOB_TOKEN_ENV}={token}");
    let me = std::process::id() as i32;
    let Ok(rd) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    rd.filter_map(|e| e.ok()?.file_name().to_str()?.parse::<i32>().ok())
        .filter(|&pid| pid != me)
        .filter(|pid| {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            // State is the field after the parenthesised command name.
            let state = stat
                .rsplit(')')
                .next()
                .and_then(|r| r.split_whitespace().next());
            !matches!(state, Some("Z") | Some("X") | None)
        })
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/environ"))
                .map(|env| env.split(|&b| b == 0).any(|v| v == needle.as_bytes()))
                .unwrap_or(false)
        })
        .collect()
}

#[cfg(not(target_os = "linux"))]
fn processes_with_token(_token: &str) -> Vec<i32> {
    Vec::new()
}

/// Kill the child's process group and every process carrying the job token (setsid
/// escapees), repeating while new ones appear (a dying parent may still fork).
#[cfg(unix)]
fn kill_tree(pgid: i32, token: &str) {
    unsafe {
        libc::kill(-pgid, libc::SIGKILL);
    }
    for _ in 0..20 {
        let left = processes_with_token(token);
        if left.is_empty() {
            break;
        }
        for pid in left {
            unsafe {
                libc::kill(pid, libc::SIGKILL);
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[cfg(not(unix))]
fn kill_tree(_pgid: i32, _token: &str) {}

/// Whether the child has exited, without reaping it (its pid, hence the process group id,
/// stays reserved until [`std::process::Child::wait`]).
#[cfg(unix)]
fn exited(child: &std::process::Child) -> std::io::Result<bool> {
    let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
    let r = unsafe {
        libc::waitid(
            libc::P_PID,
            child.id() as libc::id_t,
            &mut info,
            libc::WEXITED | libc::WNOHANG | libc::WNOWAIT,
        )
    };
    if r != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(unsafe { info.si_pid() } != 0)
}

#[cfg(not(unix))]
fn exited(child: &std::process::Child) -> std::io::Result<bool> {
    // No way to peek without reaping: fall back to try_wait's answer.
    let _ = child;
    Ok(true)
}

/// Run `argv` with the given working dir/env, logging to the two files, with a timeout.
/// Whatever way it ends (success, failure, timeout), every process the command started is
/// killed: its process group, and any process that inherited the job token.
pub(crate) fn run_logged(
    argv: &[String],
    cwd: Option<&Path>,
    env: &[(String, String)],
    stdout_log: &Path,
    stderr_log: &Path,
    timeout: Duration,
) -> Result<()> {
    let what = format!(
        "command `{}`",
        argv.first().map(String::as_str).unwrap_or("")
    );
    let ext = |message: String| Error::External {
        what: what.clone(),
        message,
    };
    let out = std::fs::File::create(stdout_log).map_err(|e| Error::io(stdout_log, e))?;
    let err = std::fs::File::create(stderr_log).map_err(|e| Error::io(stderr_log, e))?;
    let token = job_token();
    let mut cmd = Command::new(&argv[0]);
    cmd.args(&argv[1..])
        .stdin(Stdio::null())
        .stdout(Stdio::from(out))
        .stderr(Stdio::from(err));
    if let Some(d) = cwd {
        cmd.current_dir(d);
    }
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.env(JOB_TOKEN_ENV, &token);
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        cmd.process_group(0);
    }
    let mut child = cmd.spawn().map_err(|e| {
        ext(format!(
            "could not start it: {e} (is `{}` installed and on PATH?)",
            argv[0]
        ))
    })?;
    let pgid = child.id() as i32;
    let finish = |child: &mut std::process::Child| {
        kill_tree(pgid, &token);
        child.wait()
    };
    let start = Instant::now();
    let mut poll = Duration::from_millis(10);
    loop {
        match exited(&child) {
            Ok(true) => {
                let status = finish(&mut child).map_err(|e| ext(format!("wait: {e}")))?;
                if status.success() {
                    return Ok(());
                }
                return Err(ext(format!(
                    "exited with {status} after {:.1} s; stderr log {}:\n{}",
                    start.elapsed().as_secs_f64(),
                    stderr_log.display(),
                    crate::io::limits::tail_lines(stderr_log, 20)
                )));
            }
            Ok(false) => {}
            Err(e) => {
                let _ = finish(&mut child);
                return Err(ext(format!("could not wait for it: {e}")));
            }
        }
        if start.elapsed() >= timeout {
            let _ = finish(&mut child);
            return Err(ext(format!(
                "timed out after {:.1} s and was killed; logs: {} and {}",
                timeout.as_secs_f64(),
                stdout_log.display(),
                stderr_log.display()
            )));
        }
        std::thread::sleep(poll.min(timeout.saturating_sub(start.elapsed())));
        poll = (poll * 2).min(Duration::from_millis(200));
    }
}

/// Read `video_<i>/output.mp4` and `prompt.txt` of a Cosmos output folder. An empty folder
/// (the guardrail blocked the pair) and a missing one are distinct, clear errors.
pub fn ingest_output(video_dir: &Path) -> Result<(Vec<image::RgbImage>, Option<String>)> {
    if !video_dir.is_dir() {
        return Err(Error::format(
            video_dir,
            "folder",
            "a Cosmos output folder video_<i>/ with output.mp4",
            "no such folder (generation did not run for this line)",
        ));
    }
    let mp4 = video_dir.join("output.mp4");
    let empty = std::fs::read_dir(video_dir)
        .map_err(|e| Error::io(video_dir, e))?
        .next()
        .is_none();
    if empty {
        return Err(Error::format(
            video_dir,
            "output.mp4",
            "the generated video",
            "an empty folder: Cosmos' guardrail blocked this pair (prompt or video)",
        ));
    }
    if !mp4.is_file() {
        return Err(Error::format(
            video_dir,
            "output.mp4",
            "the generated video",
            "no output.mp4 in the folder",
        ));
    }
    let frames = read_mp4_frames(&mp4)?;
    let prompt_path = video_dir.join("prompt.txt");
    let prompt = if prompt_path.is_file() {
        Some(
            crate::io::limits::read_text(&prompt_path)?
                .trim_end()
                .to_string(),
        )
    } else {
        None
    };
    Ok((frames, prompt))
}

impl WfmBackend for CosmosBackend {
    fn id(&self) -> String {
        format!("cosmos:{}", self.config.command.join(" "))
    }

    fn generate(&self, req: &GenerateRequest) -> Result<Generation> {
        let mut out = self.run_batch(&req.pair_id, std::slice::from_ref(req))?;
        out.pop().unwrap_or_else(|| {
            Err(Error::Missing(format!(
                "cosmos: no result for pair {} in its batch",
                req.pair_id
            )))
        })
    }

    /// One job folder and one run of the command for every request of the same seed (the
    /// reference's `--seed` is global to a batch): line i of `batch_input.jsonl` is request i,
    /// and its video comes back from `output/video_<i>/`. A line the guardrail blocked fails
    /// alone; a failing command fails every line of its batch.
    fn generate_batch(&self, reqs: &[GenerateRequest]) -> Vec<Result<Generation>> {
        let mut out: Vec<Option<Result<Generation>>> = (0..reqs.len()).map(|_| None).collect();
        let mut seeds: Vec<u64> = reqs.iter().map(|r| r.seed).collect();
        seeds.sort_unstable();
        seeds.dedup();
        for seed in seeds {
            let idx: Vec<usize> = (0..reqs.len()).filter(|&i| reqs[i].seed == seed).collect();
            let batch: Vec<GenerateRequest> = idx.iter().map(|&i| reqs[i].clone()).collect();
            let label = format!("batch{}-seed{seed}", batch.len());
            match self.run_batch(&label, &batch) {
                Ok(rs) => {
                    for (i, r) in idx.iter().zip(rs) {
                        out[*i] = Some(r);
                    }
                }
                Err(e) => {
                    let msg = e.to_string();
                    for i in &idx {
                        out[*i] = Some(Err(Error::Invalid(format!(
                            "cosmos batch of {} pairs (seed {seed}) failed: {msg}",
                            idx.len()
                        ))));
                    }
                }
            }
        }
        out.into_iter()
            .map(|r| {
                r.unwrap_or_else(|| {
                    Err(Error::Invalid(
                        "cosmos: a request was in no seed group".into(),
                    ))
                })
            })
            .collect()
    }
}

impl CosmosBackend {
    /// Write the inputs of `reqs` (all with one seed) into one job folder, run the command
    /// once and ingest one video per line. The outer error is the command's (or the inputs');
    /// the inner ones are per line.
    fn run_batch(&self, label: &str, reqs: &[GenerateRequest]) -> Result<Vec<Result<Generation>>> {
        let c = &self.config;
        let Some(first) = reqs.first() else {
            return Ok(Vec::new());
        };
        if let Some(r) = reqs.iter().find(|r| r.seed != first.seed) {
            return Err(Error::Invalid(format!(
                "cosmos batch: seeds {} and {} in one batch (the command takes one --seed)",
                first.seed, r.seed
            )));
        }
        let single = reqs.len() == 1;
        let job = abs(&self.job_dir(label))?;
        let input = job.join("input");
        let output = job.join("output");
        std::fs::create_dir_all(&input).map_err(|e| Error::io(&input, e))?;
        std::fs::create_dir_all(&output).map_err(|e| Error::io(&output, e))?;

        let mut depth_mp4s = Vec::with_capacity(reqs.len());
        let mut jsonl = String::new();
        for (i, req) in reqs.iter().enumerate() {
            let depth_mp4 = match &req.depth_video_path {
                Some(p) => {
                    if !p.is_file() {
                        return Err(Error::format(
                            p,
                            "depth video",
                            "an existing mp4 file",
                            "no such file",
                        ));
                    }
                    abs(p)?
                }
                None => {
                    // A single request keeps the historical name `input/depth.mp4`.
                    let name = if single {
                        "depth.mp4".to_string()
                    } else {
                        format!("{i}_{}_depth.mp4", sanitize(&req.pair_id))
                    };
                    let p = input.join(name);
                    write_mp4_h264(&p, &req.depth_video, super::depth_video::FPS)?;
                    p
                }
            };
            let line = BatchLine {
                line: i,
                prompt: req.prompt.text(),
                input_control: depth_mp4.to_string_lossy().into_owned(),
                control_weight: Some(c.control_weight),
                video_save_name: Some(format!("{i}_gen_vid")),
            };
            jsonl.push_str(&line.to_json_line());
            jsonl.push('\n');
            depth_mp4s.push(depth_mp4);
        }
        let batch = job.join("batch_input.jsonl");
        write_atomic(&batch, jsonl.as_bytes())?;
        // Batch mode reads the prompt and depth input from the JSONL; the spec's own values
        // (the first line's) are defaults transfer.py requires to be present.
        let spec = job.join("controlnet_spec.json");
        write_controlnet_spec(
            &spec,
            &first.prompt.text(),
            &depth_mp4s[0],
            c.control_weight,
        )?;

        let value = |ph: &str| -> Result<String> {
            Ok(match ph {
                "{batch_input_path}" => batch.to_string_lossy().into_owned(),
                "{video_save_folder}" => output.to_string_lossy().into_owned(),
                "{controlnet_specs}" => spec.to_string_lossy().into_owned(),
                "{depth_video}" => depth_mp4s[0].to_string_lossy().into_owned(),
                "{seed}" => first.seed.to_string(),
                "{job_dir}" => job.to_string_lossy().into_owned(),
                "{checkpoint_dir}" => c
                    .checkpoint_dir
                    .as_ref()
                    .map(|p| p.to_string_lossy().into_owned())
                    .ok_or_else(|| {
                        Error::Param(
                            "cosmos backend: the command uses {checkpoint_dir} but no \
                             checkpoint directory is configured"
                                .into(),
                        )
                    })?,
                other => other.to_string(),
            })
        };
        if !single && c.command.iter().any(|a| a == "{depth_video}") {
            return Err(Error::Param(
                "cosmos batch: the command uses {depth_video}, which names one video; a batch \
                 of several pairs needs {batch_input_path}"
                    .into(),
            ));
        }
        let argv: Vec<String> = c.command.iter().map(|a| value(a)).collect::<Result<_>>()?;
        let started = Instant::now();
        run_logged(
            &argv,
            c.cwd.as_deref(),
            &c.env,
            &job.join("cosmos_stdout.log"),
            &job.join("cosmos_stderr.log"),
            c.timeout,
        )?;
        let elapsed = started.elapsed().as_secs_f64();
        Ok(reqs
            .iter()
            .enumerate()
            .map(|(i, req)| {
                self.ingest_line(req, i, reqs.len(), &job, &depth_mp4s[i], &argv, elapsed)
            })
            .collect())
    }

    #[allow(clippy::too_many_arguments)]
    fn ingest_line(
        &self,
        req: &GenerateRequest,
        line: usize,
        batch_size: usize,
        job: &Path,
        depth_mp4: &Path,
        argv: &[String],
        elapsed: f64,
    ) -> Result<Generation> {
        let c = &self.config;
        let prompt = req.prompt.text();
        let (frames, used_prompt) =
            ingest_output(&job.join("output").join(format!("video_{line}")))?;
        let mut warnings = Vec::new();
        if !c.command.iter().any(|a| a == "{seed}") {
            warnings.push(format!(
                "the command has no {{seed}} argument: seed {} was not passed to the generator",
                req.seed
            ));
        }
        if let Some(p) = &used_prompt {
            if p.trim() != prompt.trim() {
                warnings
                    .push("prompt.txt differs from the prompt sent (upsampled or edited)".into());
            }
        }
        if !req.depth_video.is_empty() && frames.len() != req.depth_video.len() {
            warnings.push(format!(
                "generated {} frames for a {}-frame depth video",
                frames.len(),
                req.depth_video.len()
            ));
        }
        let mut params = serde_json::json!({
            "control_weight": c.control_weight,
            "timeout_s": c.timeout.as_secs_f64(),
            "job_dir": job.to_string_lossy(),
            "depth_video": depth_mp4.to_string_lossy(),
            "cwd": c.cwd.as_ref().map(|p| p.to_string_lossy().into_owned()),
            "elapsed_s": elapsed,
        });
        if batch_size > 1 {
            // Elapsed time is the whole batch's; per pair it is shared.
            params["batch_line"] = line.into();
            params["batch_size"] = batch_size.into();
        }
        let frame_count = frames.len();
        Ok(Generation {
            frames,
            provenance: Provenance {
                backend: self.id(),
                model: c.model.clone(),
                command: Some(argv.to_vec()),
                prompt: used_prompt.unwrap_or(prompt),
                seed: req.seed,
                params,
                created_unix: now_unix(),
                frame_count,
                warnings,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_validation() {
        let cfg = |cmd: &[&str]| {
            CosmosConfig::new(
                cmd.iter().map(|s| s.to_string()).collect(),
                "/tmp",
                Duration::from_secs(1),
            )
        };
        assert!(CosmosBackend::new(cfg(&[])).is_err());
        let e = CosmosBackend::new(cfg(&["x", "{batch_input}"]))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("{batch_input}"), "{e}");
        assert!(CosmosBackend::new(cfg(&["x", "{batch_input_path}", "--a={seed}"])).is_ok());
        let r = CosmosConfig::reference(Path::new("/c"), Path::new("/ck"), 2, "/w");
        assert!(r.command.contains(&"--sigma_max".to_string()));
        assert!(CosmosBackend::new(r).is_ok());
    }

    /// Wait until every pid in `file` is gone (dead or a zombie), at most `secs`.
    #[cfg(target_os = "linux")]
    fn all_gone(file: &Path, secs: u64) -> bool {
        let text = std::fs::read_to_string(file).unwrap();
        let pids: Vec<i32> = text
            .split_whitespace()
            .map(|p| p.parse().unwrap())
            .collect();
        assert!(!pids.is_empty());
        let alive = |pid: i32| {
            std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .map(|s| {
                    let st = s
                        .rsplit(')')
                        .next()
                        .and_then(|r| r.split_whitespace().next());
                    !matches!(st, Some("Z") | Some("X"))
                })
                .unwrap_or(false)
        };
        let t = Instant::now();
        while t.elapsed().as_secs() < secs {
            if pids.iter().all(|&p| !alive(p)) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        false
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn children_and_setsid_grandchildren_die_with_the_command() {
        let d = tempfile::tempdir().unwrap();
        let pids = d.path().join("pids");
        let (out, err) = (d.path().join("o.log"), d.path().join("e.log"));
        let sh = |script: &str| -> Vec<String> {
            vec![
                "sh".into(),
                "-c".into(),
                script.replace("PIDS", pids.to_str().unwrap()),
            ]
        };
        // Success: a background child and a setsid grandchild outlive `sh` unless killed.
        run_logged(
            &sh("sleep 300 & echo $! > PIDS; setsid sleep 300 & echo $! >> PIDS; exit 0"),
            None,
            &[],
            &out,
            &err,
            Duration::from_secs(30),
        )
        .unwrap();
        assert!(all_gone(&pids, 5), "children survived a successful exit");
        // Timeout: the setsid grandchild left the process group, the token still finds it.
        let t = Instant::now();
        let e = run_logged(
            &sh("setsid sleep 300 & echo $! > PIDS; sleep 300"),
            None,
            &[],
            &out,
            &err,
            Duration::from_millis(500),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("timed out"), "{e}");
        assert!(t.elapsed().as_secs() < 10);
        assert!(
            all_gone(&pids, 5),
            "a setsid grandchild survived the timeout"
        );
    }

    #[test]
    fn failure_quotes_a_bounded_log_tail() {
        let d = tempfile::tempdir().unwrap();
        let (out, err) = (d.path().join("o.log"), d.path().join("e.log"));
        // 5 MB of stderr; the message shows only its last 20 lines.
        let script = "i=0; while [ $i -lt 50000 ]; do echo \"noise line $i padded to make it long ......................................................\" >&2; i=$((i+1)); done; echo LAST >&2; exit 3";
        let e = run_logged(
            &["sh".into(), "-c".into(), script.into()],
            None,
            &[],
            &out,
            &err,
            Duration::from_secs(120),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("LAST") && e.contains("earlier bytes not shown"),
            "{e}"
        );
        assert!(e.len() < 4000, "{} bytes of message", e.len());
    }

    #[test]
    fn spec_json_shape() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("spec.json");
        write_controlnet_spec(&p, "caf\u{e9}", Path::new("/v/d.mp4"), 1.0).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.is_ascii());
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["depth"]["input_control"], "/v/d.mp4");
        assert_eq!(v["depth"]["control_weight"], 1.0);
        assert_eq!(v["prompt"], "caf\u{e9}");
    }
}
