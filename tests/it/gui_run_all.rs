//! "Run all" through the worker on the staged 7-Scenes redkitchen pairs, geometry only (FPFH
//! and the default estimator): `Command::RunAll` fills every row of the pair browser with the
//! metrics that running that pair alone gives, leaves the current pair as it was, and Cancel
//! stops it between pairs.
#![cfg(feature = "gui")]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cgenreg::app::channel::{RunProgress, RunSelection};
use cgenreg::app::model::{InspectorModel, PairEntry, PairStatus};
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{spawn_worker, Command, WorkerEvent, WorkerHandle};
use cgenreg::cache::Cache;
use cgenreg::pipeline::RegisterParams;

/// The staged data, or None (skip) outside CI; under CI=true it must exist.
fn data_root() -> Option<PathBuf> {
    let p = std::env::var_os("CGENREG_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if p.join("3dmatch-redkitchen").is_dir() {
        return Some(p);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but the staged data is missing at {}", p.display());
    }
    eprintln!("skipping: no data at {}", p.display());
    None
}

/// A geometry-only worker on the staged manifest with its own (empty) stage cache; keypoints on
/// a 10 cm grid (a quarter of the default count: what Run all is checked for does not depend on
/// it).
fn worker(cache: &Path) -> PipelineWorker {
    worker_with(
        cache,
        RegisterParams {
            voxel: 0.1,
            ..Default::default()
        },
    )
}

fn worker_with(cache: &Path, params: RegisterParams) -> PipelineWorker {
    let manifest =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-staged.toml");
    let mut w = PipelineWorker::open_manifest(&manifest, params).unwrap();
    assert!(w.params().image.is_none(), "the default runs geometry only");
    w.set_cache(Some(Cache::open(cache).unwrap()));
    w
}

fn close(a: Option<f64>, b: Option<f64>) -> bool {
    match (a, b) {
        (Some(x), Some(y)) => x == y || (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1.0),
        (None, None) => true,
        _ => false,
    }
}

/// Collects the events of `h` into `seen` until `done(seen)` holds (or the time runs out).
fn wait_for(
    h: &WorkerHandle,
    seen: &mut Vec<WorkerEvent>,
    limit: Duration,
    done: impl Fn(&[WorkerEvent]) -> bool,
) {
    let t0 = Instant::now();
    loop {
        seen.extend(h.poll());
        if done(seen) {
            return;
        }
        assert!(
            t0.elapsed() < limit,
            "timed out waiting; saw {} events",
            seen.len()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The end of a run, and the model sent after it.
fn run_ended(seen: &[WorkerEvent]) -> bool {
    seen.iter().position(finished).is_some_and(|i| {
        seen[i + 1..]
            .iter()
            .any(|e| matches!(e, WorkerEvent::Model(_)))
    })
}

fn shows_a_done_pair(e: &WorkerEvent) -> bool {
    matches!(e, WorkerEvent::Model(m)
        if m.current_pair.is_some_and(|i| m.pairs[i].status == PairStatus::Done))
}

fn first_row_done(seen: &[WorkerEvent]) -> bool {
    seen.iter()
        .any(|e| matches!(e, WorkerEvent::RunAll(RunProgress { row: Some(_), .. })))
}

fn finished(e: &WorkerEvent) -> bool {
    matches!(e, WorkerEvent::RunAll(RunProgress { finished: true, .. }))
}

fn last_model(seen: &[WorkerEvent]) -> InspectorModel {
    seen.iter()
        .rev()
        .find_map(|e| match e {
            WorkerEvent::Model(m) => Some((**m).clone()),
            _ => None,
        })
        .expect("no model sent")
}

#[test]
fn run_all_fills_every_row_as_running_the_pair_alone_and_keeps_the_current_pair() {
    let Some(data) = data_root() else { return };
    crate::common::export_data_env(&data);
    let dir = tempfile::tempdir().unwrap();
    let w = worker(dir.path());
    let ids = w.pair_ids();
    let h = spawn_worker(Box::new(w), None);
    let mut seen = Vec::new();
    // the current pair first, as in the inspector
    let first = ids[0].clone();
    h.send(Command::SelectPair(first.clone()));
    wait_for(&h, &mut seen, Duration::from_secs(600), |s| {
        s.iter().any(shows_a_done_pair)
    });
    let before = last_model(&seen);
    seen.clear();
    let t = Instant::now();
    h.send(Command::RunAll(RunSelection::All));
    // the final model follows the finished event
    wait_for(&h, &mut seen, Duration::from_secs(1800), run_ended);
    eprintln!(
        "run all: {} pairs in {:.1} s",
        ids.len(),
        t.elapsed().as_secs_f64()
    );

    // one event before and one after each pair, in the dataset's order, then the end
    let steps: Vec<&RunProgress> = seen
        .iter()
        .filter_map(|e| match e {
            WorkerEvent::RunAll(p) => Some(p),
            _ => None,
        })
        .collect();
    assert_eq!(steps.len(), 2 * ids.len() + 1);
    for (i, id) in ids.iter().enumerate() {
        let (a, b) = (steps[2 * i], steps[2 * i + 1]);
        assert_eq!(
            (a.done, a.total, &a.pair, a.row.is_none()),
            (i, ids.len(), id, true)
        );
        assert_eq!((b.done, &b.pair), (i + 1, id));
        assert_eq!(b.row.as_ref().map(|r| &r.id), Some(id));
    }
    let end = steps.last().unwrap();
    assert!(end.finished && !end.cancelled && end.done == ids.len());

    // the current pair and its model are unchanged; every row is filled
    let after = last_model(&seen);
    assert_eq!(after.current_pair, before.current_pair);
    assert_eq!(after.estimated, before.estimated);
    assert_eq!(after.matches.len(), before.matches.len());
    assert_eq!(after.pairs.len(), ids.len());

    // each row equals a run of that pair alone, in a fresh worker on the same stage cache (it
    // loads the FPFH features the run wrote, as a second session would; the cache's own
    // correctness is tested in geometry_cache and cache_safety)
    let mut alone = worker(dir.path());
    let mut rows_ok = 0;
    for (id, row) in ids.iter().zip(&after.pairs) {
        assert_eq!(&row.id, id);
        assert!(!row.split.is_empty(), "{id}: no split");
        match alone.run_pair(id) {
            Ok(m) => {
                let one: &PairEntry = &m.pairs[m.current_pair.unwrap()];
                assert_eq!(row.status, PairStatus::Done, "{id}: {:?}", row.status);
                assert!(
                    close(row.rre_deg, one.rre_deg),
                    "{id}: RRE {row:?} vs {one:?}"
                );
                assert!(close(row.rte_m, one.rte_m), "{id}: RTE {row:?} vs {one:?}");
                assert!(
                    close(row.inlier_ratio, one.inlier_ratio),
                    "{id}: {row:?} vs {one:?}"
                );
                assert_eq!(row.correspondences, one.correspondences, "{id}");
                assert_eq!(row.success, one.success, "{id}");
                assert!(row.rre_deg.is_some() && row.time_ms.is_some_and(|t| t > 0.0));
                rows_ok += 1;
            }
            Err(e) => assert!(
                matches!(&row.status, PairStatus::Failed(why) if *why == e.to_string()),
                "{id}: alone it fails with {e}, the run-all row is {:?}",
                row.status
            ),
        }
    }
    assert!(
        rows_ok >= ids.len() - 1,
        "only {rows_ok} of {} pairs registered",
        ids.len()
    );
    // most staged 3DMatch pairs register with FPFH alone
    let successes = after
        .pairs
        .iter()
        .filter(|p| p.success == Some(true))
        .count();
    assert!(
        successes >= ids.len() / 2,
        "{successes} successes of {}",
        ids.len()
    );

    // "run failed/pending" picks only the rows that are not successes
    seen.clear();
    h.send(Command::RunAll(RunSelection::FailedOrPending));
    wait_for(&h, &mut seen, Duration::from_secs(1800), run_ended);
    let end = seen.iter().rev().find_map(|e| match e {
        WorkerEvent::RunAll(p) => Some(p.clone()),
        _ => None,
    });
    assert_eq!(end.map(|p| p.total), Some(ids.len() - successes));
}

#[test]
fn cancel_stops_run_all_between_pairs() {
    let Some(data) = data_root() else { return };
    crate::common::export_data_env(&data);
    let dir = tempfile::tempdir().unwrap();
    // The default keypoints: a pair takes long enough that the Cancel sent after the first
    // row lands while the second pair runs.
    let w = worker_with(dir.path(), RegisterParams::default());
    let n = w.pair_ids().len();
    let h = spawn_worker(Box::new(w), None);
    let mut seen = Vec::new();
    h.send(Command::RunAll(RunSelection::All));
    // Cancel as soon as the first pair is done
    wait_for(&h, &mut seen, Duration::from_secs(600), first_row_done);
    h.send(Command::Cancel);
    wait_for(&h, &mut seen, Duration::from_secs(600), run_ended);
    let end = seen
        .iter()
        .rev()
        .find_map(|e| match e {
            WorkerEvent::RunAll(p) => Some(p.clone()),
            _ => None,
        })
        .unwrap();
    assert!(end.cancelled, "{end:?}");
    // the pair running when Cancel came finishes; none after it starts
    assert!((1..=2).contains(&end.done) && end.done < n, "{end:?}");
    let m = last_model(&seen);
    let ran = m
        .pairs
        .iter()
        .filter(|p| p.status != PairStatus::Pending)
        .count();
    assert_eq!(ran, end.done);
    assert!(m.pairs[end.done..]
        .iter()
        .all(|p| p.status == PairStatus::Pending));
    // a new run starts afresh (the flag is cleared)
    seen.clear();
    h.send(Command::RunAll(RunSelection::FailedOrPending));
    wait_for(&h, &mut seen, Duration::from_secs(600), first_row_done);
    h.send(Command::Cancel);
    wait_for(&h, &mut seen, Duration::from_secs(600), run_ended);
}
