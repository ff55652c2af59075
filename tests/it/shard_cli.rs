//! Sharded, resumable `bench` through the CLI on the staged real data (skipped when it is
//! missing, failing under CI=true): three shards merged equal one unsharded run pair by pair
//! and in the summary; a re-run resumes; a pair whose reader fails or panics is recorded with
//! its reason and the run goes on; eight processes filling one cache at once leave it clean and
//! equal to a single writer's.

use crate::common;

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cgenreg"));
    c.env_remove("CGENREG_CACHE");
    c
}

fn staged() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-staged.toml")
}

fn run_ok(c: &mut Command) -> Output {
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "{:?} failed: {}\n{}",
        c,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn read(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// Per-pair results and summaries without timings (they differ between runs).
fn results(v: &Value) -> (Value, Value) {
    let strip = |x: &Value| cgenreg::pipeline::shard::strip_times(x);
    let pairs: Vec<Value> = v["records"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            serde_json::json!({"id": r["id"], "status": r["status"], "result": strip(&r["result"])})
        })
        .collect();
    (Value::Array(pairs), strip(&v["summary"]))
}

#[test]
fn three_shards_merged_equal_one_run_and_a_rerun_resumes() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let common = |c: &mut Command| {
        c.arg("bench")
            .arg(staged())
            .args(["--limit", "5", "--voxel", "0.05"])
            .env("CGENREG_DATA", &data)
            .arg("--cache-dir")
            .arg(d.join("cache"));
    };
    let mut c = bin();
    common(&mut c);
    run_ok(c.arg("--json").arg(d.join("all.json")));
    let mut shards = Vec::new();
    for i in 0..3 {
        let p = d.join(format!("s{i}.json"));
        let mut c = bin();
        common(&mut c);
        let o = run_ok(c.args(["--shard", &format!("{i}/3"), "--json"]).arg(&p));
        let err = String::from_utf8_lossy(&o.stderr);
        // one progress line per pair for a log reader (stderr is not a terminal here)
        assert!(err.contains(&format!("[shard {i}/3] 1/")), "{err}");
        shards.push(p);
    }
    let o = run_ok(
        bin()
            .arg("merge")
            .args(&shards)
            .arg("--json")
            .arg(d.join("merged.json")),
    );
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("| 3DMatch | 5 |"), "{table}");
    let all = read(&d.join("all.json"));
    let merged = read(&d.join("merged.json"));
    let (pa, sa) = results(&all);
    let (pm, sm) = results(&merged);
    assert_eq!(pa.as_array().unwrap().len(), 5);
    assert!(
        common::json_close(&pa, &pm),
        "per-pair results differ:\n{pa}\n{pm}"
    );
    assert!(
        common::json_close(&sa, &sm),
        "summaries differ:\n{sa}\n{sm}"
    );
    if pa != pm {
        eprintln!("note: equal to 1e-12 but not bit for bit:\n{pa}\n{pm}");
    }
    assert_eq!(merged["run"]["complete"], true);
    assert_eq!(all["pairs"].as_array().unwrap().len(), 5);
    // provenance: the commit, the binary's hash, the date and the machine of the run, and of
    // each shard a merged file was made from
    let binary = cgenreg::cache::hash_file(Path::new(env!("CARGO_BIN_EXE_cgenreg"))).unwrap();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs();
    let provenance = |r: &Value, what: &str| {
        let commit = r["commit"].as_str().unwrap_or_default();
        let hex = commit.trim_end_matches("+dirty");
        assert!(
            hex.len() == 40 && hex.bytes().all(|b| b.is_ascii_hexdigit()),
            "{what}: commit {commit:?}"
        );
        assert!(
            r["machine"]
                .as_str()
                .is_some_and(|m| m.contains("logical cores")),
            "{what}: machine {}",
            r["machine"]
        );
        assert!(!r["host"].as_str().unwrap_or_default().is_empty(), "{what}");
        let t = r["updated_unix"].as_u64().unwrap();
        assert!(t <= now && now - t < 3600, "{what}: date {t}, now {now}");
    };
    for (what, v) in [("bench", &all), ("merge", &merged)] {
        provenance(&v["run"], what);
        assert_eq!(
            v["run"]["identity"]["binary_blake3"],
            binary.as_str(),
            "{what}"
        );
    }
    let runs = merged["run"]["shard_runs"].as_array().unwrap();
    assert_eq!(runs.len(), 3);
    for (r, p) in runs.iter().zip(&shards) {
        provenance(r, "a merged shard");
        assert_eq!(
            r["file"].as_str().unwrap(),
            p.display().to_string(),
            "{runs:?}"
        );
    }

    // Re-running shard 1 resumes: both of its pairs are done, nothing runs.
    let mut c = bin();
    common(&mut c);
    let o = run_ok(c.args(["--shard", "1/3", "--json"]).arg(&shards[1]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("resuming")
            && err.contains("2 of 2 pairs of shard 1/3 done")
            && err.contains("0 to run"),
        "{err}"
    );
    // Other parameters are refused, saying what differs.
    let mut c = bin();
    common(&mut c);
    let o = c
        .args(["--shard", "1/3", "--fusion", "noisy-or", "--json"])
        .arg(&shards[1])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--no-resume"), "{err}");
    // Merging with a shard of another run names the difference; a missing shard is named.
    let o = bin()
        .arg("merge")
        .arg(&shards[0])
        .arg(d.join("all.json"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("shard_count: 1"),
        "{err}"
    );
    let o = bin().arg("merge").args(&shards[..2]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("missing: redkitchen/"),
        "{err}"
    );
    // status: per shard done / failed / missing, and the projection.
    let o = run_ok(bin().arg("status").args(&shards));
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.contains("in all: 5 done, 0 failed, 0 missing of 5"),
        "{s}"
    );
    assert!(s.contains("1623 pairs at that rate"), "{s}");
}

#[test]
fn a_pair_that_fails_or_panics_is_recorded_and_the_bench_goes_on() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A PLY that is not one, and an ascii PCD whose COUNT overflows a capacity (once a panic
    // in the reader, now a clear error: either way the pair fails).
    std::fs::write(
        d.join("bad.ply"),
        "ply\nformat ascii 1.0\nelement vertex x\n",
    )
    .unwrap();
    std::fs::write(
        d.join("huge.pcd"),
        "VERSION .7\nFIELDS x y z _\nSIZE 4 4 4 8\nTYPE F F F F\nCOUNT 1 1 1 2305843009213693952\n\
         WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n0 0 0 0\n",
    )
    .unwrap();
    let kitchen = data.join("3dmatch-redkitchen");
    let m = d.join("m.toml");
    std::fs::write(
        &m,
        format!(
            r#"name = "t"
root = "{root}"
# the clouds are real data outside this folder
allow_outside_root = true
[[fragments]]
id = "0"
cloud = "{k}/teaser-plusplus/cloud_bin_0.ply"
[[fragments]]
id = "1"
cloud = "{k}/3dsmoothnet/cloud_bin_1.ply"
[[fragments]]
id = "8"
cloud = "{d}/bad.ply"
[[fragments]]
id = "9"
cloud = "{d}/huge.pcd"
[[pairs]]
target = "0"
source = "8"
[[pairs]]
target = "0"
source = "1"
gt_log = "{k}/benchmark/3DMatch/gt.log"
[[pairs]]
target = "9"
source = "1"
"#,
            root = d.display(),
            k = kitchen.display(),
            d = d.display()
        ),
    )
    .unwrap();
    let out = d.join("r.json");
    let o = run_ok(bin().arg("bench").arg(&m).arg("--json").arg(&out));
    let err = String::from_utf8_lossy(&o.stderr);
    let v = read(&out);
    let recs = v["records"].as_array().unwrap();
    let st: Vec<&str> = recs.iter().map(|r| r["status"].as_str().unwrap()).collect();
    assert_eq!(st, ["failed", "done", "failed"], "{err}");
    assert!(
        recs[0]["error"].as_str().unwrap().contains("bad.ply"),
        "{}",
        recs[0]
    );
    assert!(
        recs[2]["error"].as_str().unwrap().contains("huge.pcd")
            || recs[2]["error"].as_str().unwrap().contains("panicked"),
        "{}",
        recs[2]
    );
    assert!(err.contains("2 of 3 pairs failed"), "{err}");
    assert_eq!(v["pairs"][1]["success"], true, "{}", v["pairs"][1]);
    assert_eq!(v["run"]["complete"], true);
}

/// The demo through the image branch with the built-in generator (L = 8, m = 1, K = 2).
/// `generate` on the demo (its per-pair pass registers too: keypoints on a 10 cm grid, as the
/// bench that reads the cache afterwards).
fn demo_generate(cache: &Path) -> Command {
    let mut c = bin();
    c.arg("generate")
        .arg(common::demo_manifest())
        .args([
            "--wfm", "builtin", "--frames", "8", "--margin", "1", "--k", "2", "--voxel", "0.1",
        ])
        .arg("--cache-dir")
        .arg(cache);
    c
}

/// Every entry as (stage/hash, [(file, blake3)]), from `cache list`-independent reading.
fn entries(cache: &Path) -> Vec<(String, Vec<(String, String)>)> {
    let c = cgenreg::cache::Cache::open(cache).unwrap();
    let mut v: Vec<_> = c
        .list()
        .unwrap()
        .into_iter()
        .map(|e| {
            let m = e.manifest.expect("every entry has a manifest");
            // provenance.json records when the entry was made (created_unix), so two
            // writers' copies differ there and only there; every payload must be identical
            let mut files: Vec<(String, String)> = m
                .files
                .into_iter()
                .filter(|f| f.name != "provenance.json")
                .map(|f| (f.name, f.blake3))
                .collect();
            files.sort();
            (format!("{}/{}", e.stage, e.hash), files)
        })
        .collect();
    v.sort();
    v
}

/// Writers racing for the same entries: on two cores four processes already interleave every
/// write (more only multiply the same work).
#[test]
fn four_processes_writing_the_same_cache_entries_leave_it_clean() {
    let dir = tempfile::tempdir().unwrap();
    let shared = dir.path().join("shared");
    let single = dir.path().join("single");
    let children: Vec<_> = (0..4)
        .map(|i| {
            demo_generate(&shared)
                .arg("--json")
                .arg(dir.path().join(format!("g{i}.json")))
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for ch in children {
        let o = ch.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let o = run_ok(bin().arg("cache").arg("--dir").arg(&shared).arg("verify"));
    let s = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    run_ok(&mut demo_generate(&single));
    let (a, b) = (entries(&shared), entries(&single));
    assert!(a.len() >= 5, "{a:?}\n{s}");
    assert_eq!(a, b, "four writers and one writer made different entries");
    // No writer's private folder is left behind.
    for st in std::fs::read_dir(&shared).unwrap().flatten() {
        if st.path().is_dir() {
            for e in std::fs::read_dir(st.path()).unwrap().flatten() {
                let n = e.file_name().to_string_lossy().into_owned();
                assert!(
                    !n.starts_with(".tmp-") && !n.starts_with(".trash-"),
                    "{n} left in {}",
                    st.path().display()
                );
            }
        }
    }
    // And a bench reading the shared cache gives the single writer's results.
    let bench = |cache: &Path, out: &Path| {
        run_ok(
            bin()
                .arg("bench")
                .arg(common::demo_manifest())
                .args([
                    "--wfm", "builtin", "--frames", "8", "--margin", "1", "--k", "2", "--voxel",
                    "0.1",
                ])
                .arg("--cache-dir")
                .arg(cache)
                .arg("--json")
                .arg(out),
        );
        results(&read(out))
    };
    let ra = bench(&shared, &dir.path().join("a.json"));
    let rb = bench(&single, &dir.path().join("b.json"));
    assert!(
        common::json_close(&ra.0, &rb.0) && common::json_close(&ra.1, &rb.1),
        "{ra:?}\n{rb:?}"
    );
}

/// `generate --wfm cosmos` puts the shard's missing generations in one batch (one run of the
/// command, the reference's JSONL), stores them under the keys a per-pair run uses, and a
/// second `generate` finds them all cached and runs nothing.
#[test]
fn generate_with_cosmos_runs_one_batch_per_shard_and_then_reads_the_cache() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    if Command::new("ffmpeg").arg("-version").output().is_err() {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but no ffmpeg"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let script = common::fake_cosmos_batch(d);
    let gen = |json: &str| {
        let mut c = bin();
        c.arg("generate")
            .arg(staged())
            .args([
                "--limit", "2", "--voxel", "0.1", "--wfm", "cosmos", "--k", "2", "--frames", "8",
                "--margin", "1",
            ])
            .arg("--cosmos-cmd")
            .arg(&script);
        for a in common::FAKE_COSMOS_ARGS {
            c.arg(format!("--cosmos-cmd={a}"));
        }
        c.arg("--cosmos-work-dir")
            .arg(d.join("jobs"))
            .arg("--cache-dir")
            .arg(d.join("cache"))
            .arg("--json")
            .arg(d.join(json))
            .env("CGENREG_DATA", &data);
        run_ok(&mut c)
    };
    let o = gen("g1.json");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("2 generations missing, one batch"), "{err}");
    let runs = std::fs::read_to_string(d.join("runs.log")).unwrap();
    assert_eq!(
        runs.lines().count(),
        1,
        "one Cosmos run for the shard: {runs}"
    );
    let jobs: Vec<_> = std::fs::read_dir(d.join("jobs")).unwrap().collect();
    assert_eq!(jobs.len(), 1);
    let g1 = read(&d.join("g1.json"));
    let recs = g1["records"].as_array().unwrap();
    assert_eq!(recs.len(), 2);
    for r in recs {
        assert_eq!(r["status"], "done", "{r}");
        let gen_stage = r["stages"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["stage"] == "generation")
            .unwrap();
        // The per-pair pass read the batch's output from the cache.
        assert!(
            gen_stage["status"].as_str().unwrap().contains("cache"),
            "{gen_stage}"
        );
    }
    // A second run: everything cached, the command is not run again.
    let o = gen("g2.json");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cached already"), "{err}");
    assert_eq!(
        std::fs::read_to_string(d.join("runs.log"))
            .unwrap()
            .lines()
            .count(),
        1
    );
}

/// `status` projects the generation cost of a full benchmark from the generation times the
/// shard files measured: the mean computed generation time per pair times the pairs to
/// project, in hours, checked here against the records themselves.
#[test]
fn status_projects_gpu_hours_from_the_measured_generation_time() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("bench.json");
    run_ok(
        bin()
            .arg("bench")
            .arg(common::demo_manifest())
            .args([
                "--wfm", "builtin", "--frames", "8", "--margin", "1", "--k", "2", "--voxel",
                "0.05", "--json",
            ])
            .arg(&out)
            .arg("--cache-dir")
            .arg(d.join("cache")),
    );
    let v = read(&out);
    let gen_ms: Vec<f64> = v["records"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|p| p["stages"].as_array().cloned().unwrap_or_default())
        .filter(|t| t["stage"] == "generation" && t["status"] == "computed")
        .map(|t| t["ms"].as_f64().unwrap())
        .collect();
    assert!(!gen_ms.is_empty(), "no computed generation recorded: {v}");
    let mean_s = gen_ms.iter().sum::<f64>() / gen_ms.len() as f64 / 1e3;
    let o = run_ok(
        bin()
            .arg("status")
            .arg(&out)
            .args(["--project-pairs", "1623"]),
    );
    let s = String::from_utf8_lossy(&o.stdout);
    let line = s
        .lines()
        .find(|l| l.starts_with("generation (computed, not cached, builtin):"))
        .unwrap_or_else(|| panic!("no generation projection in:\n{s}"));
    let nums: Vec<f64> = line
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .filter_map(|w| w.parse().ok())
        .collect();
    // "X s per pair, so 1623 pairs need Y hours": the built-in generator is not called GPU time
    assert!(line.contains("not a GPU figure"), "{line}");
    let (x, pairs, y) = (nums[0], nums[1], nums[2]);
    assert_eq!(pairs, 1623.0, "{line}");
    assert!(
        (x - mean_s).abs() <= 0.006,
        "{line}: measured mean {mean_s:.3} s"
    );
    assert!(
        (y - mean_s * 1623.0 / 3600.0).abs() <= 0.006 + 0.005 * y,
        "{line}: expected {:.2} hours",
        mean_s * 1623.0 / 3600.0
    );
    eprintln!("{line}");
}

/// `bench --repose-seed`: the staged 3DMatch pairs moved into other coordinate frames still
/// register (FPFH and SC2-PCR see the frame only through the voxel grid), the seed is part of
/// the run's identity (resuming the file with another seed is refused, naming it), and the
/// table says the sources were re-posed.
#[test]
fn reposed_sources_still_register_and_the_seed_is_part_of_the_run() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("r.json");
    let cache = dir.path().join("cache");
    let run = |seed: &str| {
        let mut c = bin();
        c.env("CGENREG_DATA", &data)
            .arg("bench")
            .arg(staged())
            .args(["--split", "3DMatch", "--limit", "2", "--repose-seed", seed])
            .arg("--cache-dir")
            .arg(&cache)
            .arg("--json")
            .arg(&json);
        c
    };
    run_ok(&mut run("7"));
    let v = read(&json);
    assert_eq!(v["params"]["repose_seed"], 7);
    let records = v["records"].as_array().unwrap();
    assert_eq!(records.len(), 2);
    for r in records {
        assert_eq!(r["status"], "done", "{r}");
        let (rre, rte) = (
            r["result"]["rre_deg"].as_f64().unwrap(),
            r["result"]["rte_m"].as_f64().unwrap(),
        );
        assert!(
            rre < 5.0 && rte < 0.1,
            "re-posed {}: RRE {rre}, RTE {rte}",
            r["id"]
        );
    }
    let o = run("8").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("repose_seed"), "{err}");
    let t = run_ok(bin().arg("table").arg(&json));
    let table = String::from_utf8_lossy(&t.stdout);
    assert!(table.contains("source re-posed (seed 7)"), "{table}");
}
