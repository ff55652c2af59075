//! Hostile paths, outputs and run files through the real binary: nothing from a path runs in
//! a Slurm script, outputs never go through links or over FIFOs / foreign files, run files are
//! read bounded and regular-only, stdout errors end cleanly, corrupt shard files are named,
//! an unwritable cache root is a warning, and manifests stay inside their root without ever
//! quoting a file's content. Everything here runs on temporary files and the bundled demo.

use crate::common;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cgenreg"));
    c.env_remove("CGENREG_CACHE")
        .env_remove("CGENREG_MAX_RUN_FILE_BYTES");
    c
}

fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn mkfifo(p: &Path) {
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn is_fifo(p: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::symlink_metadata(p)
        .map(|m| m.file_type().is_fifo())
        .unwrap_or(false)
}

fn is_link(p: &Path) -> bool {
    std::fs::symlink_metadata(p)
        .map(|m| m.file_type().is_symlink())
        .unwrap_or(false)
}

// ---------------------------------------------------------------- Slurm scripts

/// A file named like a manifest (slurm only checks that it exists and that the task command
/// line parses).
fn manifest_in(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let m = dir.join("m.toml");
    std::fs::write(&m, "name = \"t\"\n").unwrap();
    m
}

fn slurm(m: &Path, out: &Path) -> Output {
    bin()
        .args(["slurm", "bench"])
        .arg(m)
        .args(["--array", "2", "--out"])
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn slurm_refuses_newlines_and_other_control_characters_in_script_paths() {
    let d = tempfile::tempdir().unwrap();
    for (i, name) in [
        "x\ntouch INJECTED\n",
        "x\r\ntouch INJECTED\r\n",
        "x\u{1b}[2Jy",
        "x\ty",
    ]
    .iter()
    .enumerate()
    {
        let m = manifest_in(&d.path().join(name));
        let out = d.path().join(format!("run{i}"));
        let o = slurm(&m, &out);
        assert!(!o.status.success(), "{name:?}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("control character") && err.contains("manifest"),
            "{name:?}: {err}"
        );
        assert!(!out.join("array.sbatch").exists(), "{name:?}");
    }
    // The run folder goes into #SBATCH lines: a newline there is refused too.
    let m = manifest_in(&d.path().join("plain"));
    let o = slurm(&m, &d.path().join("r\nx"));
    assert!(!o.status.success(), "{}", text(&o));
}

#[test]
fn slurm_scripts_quote_a_hostile_manifest_path_and_run_nothing_injected() {
    let d = tempfile::tempdir().unwrap();
    let work = d.path().join("work");
    std::fs::create_dir(&work).unwrap();
    let name = "a'$(touch M1)'b;touch M2;`touch M3` \"$(touch M4)\" #x";
    let m = manifest_in(&d.path().join(name));
    let out = d.path().join("run");
    let o = slurm(&m, &out);
    assert!(o.status.success(), "{}", text(&o));
    for script in ["array.sbatch", "merge.sbatch"] {
        let p = out.join(script);
        let s = std::fs::read_to_string(&p).unwrap();
        // every line is a comment, a #SBATCH line or the one exec line
        for l in s.lines() {
            assert!(
                l.starts_with('#') || l.starts_with("exec "),
                "{script}: {l:?}"
            );
        }
        let n = Command::new("bash").arg("-n").arg(&p).output().unwrap();
        assert!(n.status.success(), "{}", text(&n));
        // Run it: the task fails at once (no SLURM_ARRAY_TASK_ID, no shards), and no
        // command from the path runs.
        let r = Command::new("bash")
            .arg(&p)
            .current_dir(&work)
            .env_remove("SLURM_ARRAY_TASK_ID")
            .output()
            .unwrap();
        assert!(!r.status.success(), "{script}: {}", text(&r));
        for mark in ["M1", "M2", "M3", "M4"] {
            assert!(!work.join(mark).exists(), "{script}: {mark} was created");
            assert!(
                !d.path().join(mark).exists(),
                "{script}: {mark} was created"
            );
        }
    }
    // The plan keeps the path exactly.
    let plan: Value =
        serde_json::from_slice(&std::fs::read(out.join("plan.json")).unwrap()).unwrap();
    assert_eq!(plan["manifest"].as_str().unwrap(), m.to_str().unwrap());
}

// ---------------------------------------------------------------- outputs

/// A run file of a `generate` run of `count` shards over pairs p0..p{n-1}, shard `index`,
/// with records for `ids` (done).
fn run_file(index: usize, count: usize, shard_count: usize, n: usize, ids: &[&str]) -> Value {
    let selected: Vec<String> = (0..n).map(|i| format!("t/p{i}")).collect();
    json!({
        "manifest": "m.toml",
        "params": {},
        "run": {
            "identity": {
                "command": "generate",
                "manifest": "m.toml",
                "manifest_blake3": "00",
                "split": null,
                "limit": null,
                "params": {},
                "shard_count": shard_count,
                "code_version": "cgenreg 0",
                "binary_blake3": "00",
                "selected": selected,
            },
            "shard": {"index": index, "count": count},
            "complete": false,
            "in_flight": null,
            "host": "h",
            "updated_unix": 0,
        },
        "records": ids.iter().map(|id| json!({
            "id": id, "status": "done", "time_s": 0.5, "stages": [], "result": {"ok": true},
        })).collect::<Vec<_>>(),
    })
}

fn write_json(p: &Path, v: &Value) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, serde_json::to_vec_pretty(v).unwrap()).unwrap();
}

/// Three complete shard files of a 3-shard run over 6 pairs.
fn three_shards(dir: &Path) -> Vec<PathBuf> {
    (0..3)
        .map(|i| {
            let p = dir.join("shards").join(format!("shard-{i}.json"));
            let ids = [format!("t/p{i}"), format!("t/p{}", i + 3)];
            write_json(&p, &run_file(i, 3, 3, 6, &[&ids[0], &ids[1]]));
            p
        })
        .collect()
}

fn merge_into(dir: &Path, out: &Path, force: bool) -> Output {
    let mut c = bin();
    c.arg("merge").arg(dir).arg("--json").arg(out);
    if force {
        c.arg("--force");
    }
    c.output().unwrap()
}

#[test]
fn merge_json_never_replaces_a_fifo_a_link_or_a_foreign_file() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    three_shards(&run);
    // A FIFO (what /dev/null is to an atomic rename): refused, still a FIFO, no hang.
    let fifo = d.path().join("null.json");
    mkfifo(&fifo);
    let o = merge_into(&run, &fifo, true);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("FIFO"),
        "{}",
        text(&o)
    );
    assert!(is_fifo(&fifo));
    // A link to another file: refused even with --force; the file and the link are kept.
    let victim = d.path().join("notes.txt");
    std::fs::write(&victim, "keep me").unwrap();
    let link = d.path().join("merged.json");
    std::os::unix::fs::symlink(&victim, &link).unwrap();
    let o = merge_into(&run, &link, true);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("symbolic link"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    assert!(is_link(&link));
    // A foreign regular file: refused without --force, replaced with it.
    let o = merge_into(&run, &victim, false);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--force"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    let out = d.path().join("out.json");
    let o = merge_into(&run, &out, false);
    assert!(o.status.success(), "{}", text(&o));
    // Its own kind of output is replaced without --force.
    let o = merge_into(&run, &out, false);
    assert!(o.status.success(), "{}", text(&o));
    let v: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(v["records"].as_array().unwrap().len(), 6);
    let o = merge_into(&run, &victim, true);
    assert!(o.status.success(), "{}", text(&o));
    // A folder that does not exist is an error, not created.
    let o = merge_into(&run, &d.path().join("no/such/m.json"), false);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(!d.path().join("no").exists());
}

#[test]
fn register_export_bench_and_generate_outputs_refuse_fifos_and_links_before_any_work() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("corr.npz");
    mkfifo(&fifo);
    let victim = d.path().join("victim.txt");
    std::fs::write(&victim, "keep me").unwrap();
    let link = d.path().join("link.npz");
    std::os::unix::fs::symlink(&victim, &link).unwrap();
    let demo = common::demo_manifest();
    for target in [&fifo, &link, &victim] {
        let o = bin()
            .args(["register", "--manifest"])
            .arg(&demo)
            .args(["--pair", "synth-room/0-1", "--no-cache", "--export-corr"])
            .arg(target)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(target.file_name().unwrap().to_str().unwrap())
                && !err.contains("registered"),
            "{err}"
        );
        let mut c = bin();
        c.arg("bench")
            .arg(&demo)
            .args(["--no-cache", "--json"])
            .arg(target);
        let o = c.output().unwrap();
        assert!(!o.status.success(), "{}", text(&o));
        let o = bin()
            .arg("generate")
            .arg(&demo)
            .args(["--wfm", "oracle", "--cache-dir"])
            .arg(d.path().join("cache"))
            .arg("--json")
            .arg(target)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{}", text(&o));
    }
    assert!(is_fifo(&fifo) && is_link(&link));
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
}

#[cfg(feature = "gui")]
#[test]
fn screenshot_out_refuses_a_foreign_file_a_link_and_a_missing_folder() {
    let d = tempfile::tempdir().unwrap();
    let txt = d.path().join("notes.txt");
    std::fs::write(&txt, "keep me").unwrap();
    let link = d.path().join("shot.png");
    std::os::unix::fs::symlink(&txt, &link).unwrap();
    let missing = d.path().join("no-such-folder").join("x.png");
    for (out, why) in [
        (&txt, "--force"),
        (&link, "symbolic link"),
        (&missing, "does not exist"),
    ] {
        let o = bin()
            .args(["screenshot", "--panel", "pairs", "--out"])
            .arg(out)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(why),
            "{}",
            text(&o)
        );
    }
    assert_eq!(std::fs::read_to_string(&txt).unwrap(), "keep me");
    assert!(is_link(&link));
    assert!(!d.path().join("no-such-folder").exists());
}

// ---------------------------------------------------------------- bounded readers

#[test]
fn every_run_file_reader_refuses_a_dev_zero_link_at_once() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    let shards = three_shards(&run);
    let zero = d.path().join("zero.json");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let fifo = d.path().join("fifo.json");
    mkfifo(&fifo);
    let shard_zero = run.join("shards").join("shard-9.json");
    std::os::unix::fs::symlink("/dev/zero", &shard_zero).unwrap();
    let mut cases: Vec<(&str, Command)> = Vec::new();
    for bad in [&zero, &fifo] {
        let mut c = bin();
        c.arg("merge").arg(bad).arg(&shards[0]);
        cases.push(("merge", c));
        let mut c = bin();
        c.arg("status").arg(bad);
        cases.push(("status", c));
        let mut c = bin();
        c.arg("table").arg(bad);
        cases.push(("table", c));
        let mut c = bin();
        c.arg("diff").arg(bad).arg(&shards[0]);
        cases.push(("diff", c));
        #[cfg(feature = "gui")]
        {
            let mut c = bin();
            c.args(["screenshot", "--panel", "compare", "--compare"])
                .arg(bad)
                .arg(&shards[0])
                .arg("--out")
                .arg(d.path().join("c.png"));
            cases.push(("screenshot --compare", c));
        }
    }
    // A run folder holding a /dev/zero link among its shards.
    let mut c = bin();
    c.arg("status").arg(&run);
    cases.push(("status DIR", c));
    let mut c = bin();
    c.arg("merge").arg(&run);
    cases.push(("merge DIR", c));
    for (what, mut c) in cases {
        let t = std::time::Instant::now();
        let mut child = c
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // a reader that read /dev/zero would run for minutes and eat the memory
        loop {
            if child.try_wait().unwrap().is_some() {
                break;
            }
            if t.elapsed().as_secs() > 60 {
                let _ = child.kill();
                panic!("{what}: still reading after 60 s");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let o = child.wait_with_output().unwrap();
        assert!(!o.status.success(), "{what}: {}", text(&o));
        let all = text(&o);
        assert!(
            (all.contains("character device") || all.contains("FIFO")) && !all.contains("panicked"),
            "{what}: {all}"
        );
    }
}

#[test]
fn an_oversized_run_file_is_refused_with_the_limit_named() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    let shards = three_shards(&run);
    for args in [vec!["status"], vec!["table"], vec!["merge"]] {
        let o = bin()
            .args(&args)
            .arg(&shards[0])
            .env("CGENREG_MAX_RUN_FILE_BYTES", "200")
            .output()
            .unwrap();
        assert!(!o.status.success(), "{args:?}: {}", text(&o));
        let all = text(&o);
        assert!(
            all.contains("CGENREG_MAX_RUN_FILE_BYTES") && all.contains("shard-0.json"),
            "{args:?}: {all}"
        );
    }
}

// ---------------------------------------------------------------- stdout

#[test]
fn a_closed_stdout_ends_with_status_0_and_a_full_one_with_a_clear_error() {
    let demo = common::demo_manifest();
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    three_shards(&run);
    let cases: Vec<Vec<std::ffi::OsString>> = vec![
        vec!["bench".into(), demo.clone().into(), "--list".into()],
        vec!["status".into(), run.clone().into()],
        vec!["merge".into(), run.clone().into()],
        vec![
            "cache".into(),
            "--dir".into(),
            d.path().join("cache").into(),
            "list".into(),
        ],
    ];
    for args in &cases {
        // the reader is gone before the first write: EPIPE
        let (r, w) = std::io::pipe().unwrap();
        drop(r);
        let o = bin().args(args).stdout(w).output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{args:?}: {}", text(&o));
        assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"));
        // /dev/full: every write fails with ENOSPC
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let o = bin().args(args).stdout(full).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        if args[0] == "cache" {
            // an empty cache lists nothing: nothing to fail on
            continue;
        }
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", text(&o));
        assert!(
            err.contains("writing to stdout") && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
}

// ---------------------------------------------------------------- corrupt shard files

#[test]
fn status_and_merge_name_every_corrupt_shard_file() {
    let deep = "[".repeat(10_000);
    let bad: Vec<(&str, Vec<u8>)> = vec![
        ("truncated", b"{\"run\": {\"identity\": ".to_vec()),
        ("empty", Vec::new()),
        ("not JSON", b"hello".to_vec()),
        ("wrong types", br#"{"run": 3, "records": "x"}"#.to_vec()),
        ("BOM", {
            let mut v = b"\xEF\xBB\xBF".to_vec();
            v.extend(serde_json::to_vec(&run_file(1, 3, 3, 6, &["t/p1"])).unwrap());
            v
        }),
        ("deeply nested", deep.into_bytes()),
        (
            "duplicated records",
            serde_json::to_vec(&run_file(1, 3, 3, 6, &["t/p1", "t/p1", "t/p4"])).unwrap(),
        ),
        (
            "shard index out of range",
            serde_json::to_vec(&run_file(5, 3, 3, 6, &[])).unwrap(),
        ),
        (
            "a 1-shard claim in a 3-shard run",
            serde_json::to_vec(&run_file(0, 1, 3, 6, &["t/p1"])).unwrap(),
        ),
        (
            "a record of another shard",
            serde_json::to_vec(&run_file(1, 3, 3, 6, &["t/p2"])).unwrap(),
        ),
    ];
    for (what, bytes) in &bad {
        let d = tempfile::tempdir().unwrap();
        let run = d.path().join("run");
        let shards = three_shards(&run);
        std::fs::write(&shards[1], bytes).unwrap();
        let o = bin().arg("status").arg(&run).output().unwrap();
        let out = String::from_utf8_lossy(&o.stdout);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{what}: {}", text(&o));
        assert!(
            out.contains("| 1/3 |") && out.contains("shard-1.json | CORRUPT"),
            "{what}: {out}"
        );
        assert!(!out.contains("(no output yet)"), "{what}: {out}");
        assert!(!out.contains("18446744073709551615"), "{what}: {out}");
        assert!(err.contains("shard-1.json"), "{what}: {err}");
        let o = bin().arg("merge").arg(&run).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{what}: {}", text(&o));
        assert!(
            err.contains("shard-1.json") && !err.contains("they resume"),
            "{what}: {err}"
        );
        // named explicitly, too
        let o = bin().arg("merge").args(&shards).output().unwrap();
        assert!(!o.status.success(), "{what}: {}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("shard-1.json"),
            "{what}: {}",
            text(&o)
        );
    }
}

// ---------------------------------------------------------------- cache root

#[test]
fn a_full_empty_cache_root_is_a_warning_and_leaves_no_tmp_files() {
    let d = tempfile::tempdir().unwrap();
    let cache = d.path().join("cache");
    std::fs::create_dir(&cache).unwrap();
    // File size limit 0 (SIGXFSZ ignored): every write into a file fails as on a full disk,
    // for root too. stdout is a pipe and is not limited.
    let script = format!(
        "trap '' XFSZ; ulimit -f 0; exec {} register --manifest {} --pair synth-room/0-1 \
         --voxel 0.05 --cache-dir {}",
        env!("CARGO_BIN_EXE_cgenreg"),
        common::demo_manifest().display(),
        cache.display()
    );
    let o = Command::new("bash")
        .args(["-c", &script])
        .env_remove("CGENREG_CACHE")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("warning") && err.contains("marker"), "{err}");
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("estimated target_from_source"),
        "{}",
        text(&o)
    );
    let mut left = Vec::new();
    let mut stack = vec![cache.clone()];
    while let Some(p) = stack.pop() {
        for e in std::fs::read_dir(&p).unwrap().flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            if n.contains(".tmp") {
                left.push(e.path());
            }
            if e.path().is_dir() {
                stack.push(e.path());
            }
        }
    }
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn cache_rm_of_an_unknown_stage_is_an_error() {
    let d = tempfile::tempdir().unwrap();
    let cache = d.path().join("cache");
    let o = bin()
        .arg("cache")
        .arg("--dir")
        .arg(&cache)
        .arg("init")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let o = bin()
        .arg("cache")
        .arg("--dir")
        .arg(&cache)
        .args(["rm", "generaton"])
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("no stage of that name"),
        "{}",
        text(&o)
    );
}

// ---------------------------------------------------------------- manifests

const SECRET: &str = "root:x:0:0:SECRET-LINE:/root:/bin/bash";

fn list(m: &Path) -> Output {
    bin().arg("bench").arg(m).arg("--list").output().unwrap()
}

#[test]
fn manifest_paths_stay_inside_the_root_unless_allowed_and_errors_never_quote_content() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("root");
    std::fs::create_dir(&root).unwrap();
    let outside = d.path().join("passwd");
    std::fs::write(&outside, format!("{SECRET}\nother:x:1:1::/:/bin/sh\n")).unwrap();
    std::os::unix::fs::symlink(&outside, root.join("inside.ply")).unwrap();
    std::fs::write(root.join("ok.ply"), "ply\n").unwrap();
    let body = |cloud: &str, allow: bool| {
        format!(
            "name = \"t\"\n{}[[fragments]]\nid = \"0\"\ncloud = \"{cloud}\"\n\
             [[fragments]]\nid = \"1\"\ncloud = \"ok.ply\"\n[[pairs]]\ntarget = \"0\"\nsource = \"1\"\n",
            if allow { "allow_outside_root = true\n" } else { "" }
        )
    };
    let abs = outside.display().to_string();
    for cloud in ["../passwd", "inside.ply", abs.as_str()] {
        let m = root.join("m.toml");
        std::fs::write(&m, body(cloud, false)).unwrap();
        let o = list(&m);
        assert!(!o.status.success(), "{cloud}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("outside the root") && err.contains("allow_outside_root"),
            "{cloud}: {err}"
        );
        // allowed: the file is read, and its error does not quote it
        std::fs::write(&m, body(cloud, true)).unwrap();
        assert!(list(&m).status.success(), "{cloud}");
        let o = bin()
            .args(["register", "--manifest"])
            .arg(&m)
            .args(["--pair", "t/0-1"])
            .output()
            .unwrap();
        assert!(!o.status.success(), "{cloud}: {}", text(&o));
        let all = text(&o);
        assert!(
            !all.contains("SECRET") && !all.contains("root:x"),
            "{cloud}: {all}"
        );
    }
    // The readers themselves never echo a line, whatever the format.
    for ext in ["ply", "pcd", "xyz", "txt"] {
        let p = d.path().join(format!("secret.{ext}"));
        std::fs::copy(&outside, &p).unwrap();
        let o = bin()
            .args(["register", "--source"])
            .arg(&p)
            .arg("--target")
            .arg(&p)
            .output()
            .unwrap();
        let all = text(&o);
        assert!(!o.status.success(), "{ext}: {all}");
        assert!(all.contains("secret."), "{ext}: {all}");
        assert!(
            !all.contains("SECRET") && !all.contains("root:x"),
            "{ext}: {all}"
        );
    }
}

#[test]
fn a_gt_file_that_is_a_fifo_is_named_as_one_not_as_missing() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.xyz"), "0 0 0\n1 0 0\n0 1 0\n").unwrap();
    mkfifo(&d.path().join("gt.txt"));
    let m = d.path().join("m.toml");
    std::fs::write(
        &m,
        "name = \"t\"\n[[fragments]]\nid = \"0\"\ncloud = \"a.xyz\"\n[[fragments]]\nid = \"1\"\n\
         cloud = \"a.xyz\"\n[[pairs]]\ntarget = \"0\"\nsource = \"1\"\ngt_file = \"gt.txt\"\n",
    )
    .unwrap();
    let o = list(&m);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        err.contains("gt_file") && err.contains("FIFO") && !err.contains("not found"),
        "{err}"
    );
}
