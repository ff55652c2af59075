//! Tests of `pipeline::shard`.

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
            machine: None,
            commit: None,
            shard_runs: Vec::new(),
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
    let (mut p, msg) = Progress::start(id.clone(), shard, Some(&out), ResumeMode::Resume).unwrap();
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
    // a run holds its run file's lock until it ends: each start below is a new run
    drop(p);
    let (p, _) = Progress::start(id.clone(), shard, Some(&out), ResumeMode::Restart).unwrap();
    assert_eq!(p.pending(), vec![1, 3, 5]);
    drop(p);

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
fn catch_panic_turns_panics_into_errors() {
    use crate::error::catch_panic;
    let e = catch_panic::<()>(|| panic!("reader exploded at byte {}", 7)).unwrap_err();
    assert!(matches!(e, Error::Panicked(_)), "{e:?}");
    assert_eq!(e.to_string(), "panicked: reader exploded at byte 7");
    assert_eq!(catch_panic(|| Ok(3)).unwrap(), 3);
    let e = catch_panic::<()>(|| std::panic::panic_any(7u8)).unwrap_err();
    assert_eq!(e.to_string(), "panicked: (no message)");
}

#[test]
fn strip_times_removes_only_timings() {
    let v = json!({"time_s": 1, "rre_deg": 2, "x": [{"ms": 3, "stage": "a"}]});
    assert_eq!(
        strip_times(&v),
        json!({"rre_deg": 2, "x": [{"stage": "a"}]})
    );
}
