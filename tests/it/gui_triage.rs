//! The pair browser's triage on a real run: eleven pairs of the whole redkitchen benchmark
//! (3DMatch and 3DLoMatch, failures and consecutive-fragment pairs among them), laid out as
//! Predator does and written by `cgenreg dataset 3dmatch`'s library function, run through
//! `cgenreg bench` (no option: geometry, the indoor preset) and through the inspector's worker
//! with the settings bench recorded: the browser's
//! summary rows are bench's `field` rows (to 1e-12), and the filters, failures first and the
//! next-failure walk agree with bench's verdicts. Also, headless: the frame time of the Pairs
//! tab at 1,031 rows against 103 rows (printed; only layout that grows with the row count
//! fails it).
#![cfg(feature = "gui")]

use std::os::unix::fs::symlink;
use std::path::{Path, PathBuf};
use std::time::Instant;

use cgenreg::app::channel::{RunProgress, RunSelection};
use cgenreg::app::headless::HeadlessRenderer;
use cgenreg::app::model::{PairEntry, PairStatus, SettingsTag};
use cgenreg::app::pair_order::{visible_pairs, OutcomeFilter, PairFilter, PairSort};
use cgenreg::app::triage::{is_failure, next_failure, summary_rows};
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{InspectorModel, Panel};
use cgenreg::pipeline::RegisterParams;

const SCENE: &str = "7-scenes-redkitchen";

/// (split, target, source): successes, failures (by the committed whole-benchmark run) and
/// pairs of consecutive fragments (not counted by the official recall), small fragments first.
const PAIRS: [(&str, u32, u32); 11] = [
    ("3DMatch", 46, 51),
    ("3DMatch", 46, 52),
    ("3DMatch", 44, 46),
    ("3DMatch", 47, 48),
    ("3DMatch", 44, 45),
    ("3DMatch", 6, 53),
    ("3DMatch", 7, 53),
    ("3DLoMatch", 11, 50),
    ("3DLoMatch", 15, 50),
    ("3DLoMatch", 16, 48),
    ("3DLoMatch", 0, 48),
];

/// The eleven pairs' manifest, written under `dir` (None: skip without the data).
fn small_manifest(dir: &Path) -> Option<PathBuf> {
    let data = cgenreg::testing::test_data_root()?;
    let frags = cgenreg::testing::require_file(&data, "3dmatch-redkitchen-full/cloud_bin_59.pth")?;
    let bench =
        cgenreg::testing::require_file(&data, "3dmatch-redkitchen/benchmark/3DLoMatch/gt.info")?;
    let (frags, bench) = (frags.parent()?, bench.parent()?.parent()?);
    let root = dir.join("3dmatch");
    std::fs::create_dir_all(&root).unwrap();
    symlink(frags, root.join(SCENE)).unwrap();
    for b in ["3DMatch", "3DLoMatch"] {
        let d = root.join("benchmarks").join(b).join(SCENE);
        std::fs::create_dir_all(&d).unwrap();
        for f in ["gt.log", "gt.info"] {
            symlink(bench.join(b).join(f), d.join(f)).unwrap();
        }
    }
    let text = cgenreg::dataset::official::threedmatch_manifest(&root, None, None)
        .unwrap()
        .text;
    let mut blocks = text.split("\n[[pairs]]\n");
    let mut out = blocks.next().unwrap().to_string();
    for b in blocks {
        let has = |k: &str, v: &str| b.lines().any(|l| l.trim() == format!("{k} = \"{v}\""));
        if PAIRS.iter().any(|(s, t, src)| {
            has("split", s) && has("target", &t.to_string()) && has("source", &src.to_string())
        }) {
            out.push_str("\n[[pairs]]\n");
            out.push_str(b);
        }
    }
    let path = dir.join("small.toml");
    std::fs::write(&path, out).unwrap();
    Some(path)
}

#[test]
fn summary_rows_filters_and_failures_match_bench_on_a_real_run() {
    let d = tempfile::tempdir().unwrap();
    let Some(manifest) = small_manifest(d.path()) else {
        return;
    };
    // bench on the manifest (geometry alone, the indoor preset: no option)
    let json = d.path().join("bench.json");
    let t = Instant::now();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .arg("bench")
        .arg(&manifest)
        .args(["--no-cache", "--json"])
        .arg(&json)
        .output()
        .unwrap();
    let bench_s = t.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();

    // the inspector: Run all with the settings bench ran with (as recorded), no stage cache
    let params: RegisterParams = serde_json::from_value(v["params"].clone()).unwrap();
    let mut w = PipelineWorker::open_manifest(&manifest, params).unwrap();
    w.set_cache(None);
    assert!(w.params().image.is_none());
    let t = Instant::now();
    let mut events: Vec<RunProgress> = Vec::new();
    let s = w.run_all(RunSelection::All, &mut |p| events.push(p));
    let run_s = t.elapsed().as_secs_f64();
    assert_eq!(
        (s.total, s.done, s.cancelled),
        (PAIRS.len(), PAIRS.len(), false)
    );
    // results stream in: a row after each pair, the count rising to the end
    let rows_in: Vec<usize> = events
        .iter()
        .filter(|e| e.row.is_some())
        .map(|e| e.done)
        .collect();
    assert_eq!(rows_in, (1..=PAIRS.len()).collect::<Vec<_>>());
    assert!(events.last().unwrap().finished);
    let pairs: Vec<PairEntry> = w.pair_rows().to_vec();
    let current = SettingsTag::of(w.params()).id;
    assert!(pairs.iter().all(|p| p.scene.as_deref() == Some(SCENE)));
    // the official recall counts the pairs of non-consecutive fragments only
    let counted = |id: &str| pairs.iter().find(|p| p.id.ends_with(id)).unwrap();
    assert!(counted("/47-48").rmse_ref.is_none() && counted("/46-51").rmse_ref.is_some());
    assert!(counted("/46-51").rmse_m.is_some_and(|r| r < 0.2));

    eprintln!(
        "{} pairs: inspector {run_s:.1} s, bench {bench_s:.1} s",
        PAIRS.len()
    );

    // the summary rows are bench's, through the same function (to 1e-12: two runs of a pair
    // can differ in a pose's last bit)
    let (field, n) = summary_rows(&pairs, Some(&current));
    assert_eq!(n, PAIRS.len());
    let mine = serde_json::to_value(&field).unwrap();
    assert!(
        crate::common::json_close(&mine, &v["field"]),
        "{mine}\n{}",
        v["field"]
    );
    let splits: Vec<(&str, Option<&str>)> = field
        .iter()
        .map(|r| (r.benchmark.as_str(), r.scene.as_deref()))
        .collect();
    assert_eq!(
        splits,
        [
            ("3DLoMatch", Some(SCENE)),
            ("3DLoMatch", None),
            ("3DMatch", Some(SCENE)),
            ("3DMatch", None)
        ]
    );
    // a partial run's rows cover the pairs run so far, and say so by their count
    let mut half = pairs.clone();
    for p in half.iter_mut().take(4) {
        p.reset(PairStatus::Pending);
    }
    assert_eq!(summary_rows(&half, Some(&current)).1, PAIRS.len() - 4);
    // rows of other settings never count
    assert_eq!(summary_rows(&pairs, Some("other")).1, 0);

    // bench's verdicts
    let failed: Vec<String> = v["pairs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["success"] != serde_json::Value::Bool(true))
        .map(|p| p["id"].as_str().unwrap().to_string())
        .collect();
    assert!(
        failed.len() >= 2 && failed.len() < PAIRS.len(),
        "{failed:?}"
    );
    let ids = |rows: &[usize]| -> Vec<String> {
        let mut v: Vec<String> = rows.iter().map(|&i| pairs[i].id.clone()).collect();
        v.sort();
        v
    };
    let sort = PairSort::WORST_RRE;
    // outcome filter: exactly bench's failures
    let f = PairFilter {
        outcome: OutcomeFilter::FailureOrError,
        ..Default::default()
    };
    let mut want = failed.clone();
    want.sort();
    assert_eq!(ids(&visible_pairs(&pairs, &f, sort)), want);
    // split and scene filters
    let lo = PairFilter {
        split: Some("3DLoMatch".into()),
        scene: Some(SCENE.into()),
        ..Default::default()
    };
    let rows = visible_pairs(&pairs, &lo, sort);
    assert_eq!(rows.len(), 4);
    assert!(rows.iter().all(|&i| pairs[i].split == "3DLoMatch"));
    let other = PairFilter {
        scene: Some("another-scene".into()),
        ..Default::default()
    };
    assert!(visible_pairs(&pairs, &other, sort).is_empty());
    // failures first: bench's failures on top, in the sort's order
    let ff = PairFilter {
        failures_first: true,
        ..Default::default()
    };
    let order = visible_pairs(&pairs, &ff, PairSort::BY_NAME);
    assert_eq!(ids(&order[..failed.len()]), want);
    // next failure: from the top through every failure once, in the shown order, then around
    let mut at = None;
    let mut seen = Vec::new();
    for _ in 0..failed.len() {
        let i = next_failure(&pairs, &order, at, true, Some(&current)).unwrap();
        assert!(is_failure(&pairs[i], Some(&current)));
        seen.push(i);
        at = Some(i);
    }
    assert_eq!(seen, order[..failed.len()].to_vec());
    assert_eq!(
        next_failure(&pairs, &order, at, true, Some(&current)),
        Some(seen[0])
    );
}

/// 1,031 realistic rows (the whole redkitchen benchmark's ids, splits and scene, a tenth of
/// them failures) or the first `n`.
fn rows(n: usize) -> Vec<PairEntry> {
    let mut out = Vec::new();
    'all: for t in 0..60u32 {
        for s in (t + 1)..60 {
            let k = out.len();
            if k == n {
                break 'all;
            }
            let rre = 0.3 + (k * 37 % 101) as f64 * 0.2;
            out.push(PairEntry {
                id: format!("{SCENE}/{t}-{s}"),
                split: if k % 2 == 0 { "3DMatch" } else { "3DLoMatch" }.into(),
                scene: Some(SCENE.into()),
                status: PairStatus::Done,
                rre_deg: Some(rre),
                rte_m: Some(rre * 0.02),
                success: Some(rre <= 15.0 && rre * 0.02 <= 0.3),
                inlier_ratio: Some(0.1),
                correspondences: Some(4000 + k),
                time_ms: Some(300.0),
                ..Default::default()
            });
        }
    }
    out
}

/// Median frame time (ms) of the Pairs tab over `rows` rows, scrolled to the middle.
fn pairs_frame_ms(rows: Vec<PairEntry>) -> Option<f64> {
    let model = InspectorModel {
        current_pair: Some(rows.len() / 2),
        pairs: rows,
        ..Default::default()
    };
    let mut r = match HeadlessRenderer::new(model, (1600, 1000)) {
        Ok(r) => r,
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => panic!("CI=true but no EGL: {e}"),
        Err(e) => {
            eprintln!("skipping: {e}");
            return None;
        }
    };
    r.app.ui_state.tab = Panel::Pairs;
    r.app.tabs.pairs.filter.failures_first = true;
    for _ in 0..3 {
        r.frame(false).unwrap();
    }
    let mut t: Vec<f64> = (0..9)
        .map(|_| {
            let t0 = Instant::now();
            r.frame(false).unwrap();
            t0.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    Some(t[t.len() / 2])
}

#[test]
fn pairs_tab_frame_time_does_not_grow_with_the_rows() {
    let full = rows(1031);
    assert_eq!(full.len(), 1031);
    let Some(small) = pairs_frame_ms(full[..103].to_vec()) else {
        return;
    };
    let Some(big) = pairs_frame_ms(full) else {
        return;
    };
    eprintln!(
        "Pairs tab, headless frame (median of 9): 103 rows {small:.1} ms, 1031 rows {big:.1} ms"
    );
    // every row laid out would cost about ten times as much at ten times the rows; the bound
    // is generous (a busy machine), and catches only that
    assert!(big < 3.0 * small + 25.0, "{big:.1} ms vs {small:.1} ms");
}
