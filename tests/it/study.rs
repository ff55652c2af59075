//! Parameter studies (figure 6: K sweep; figure 4: prompt categories) on the bundled demo with
//! the built-in generator (NOT a WFM) + XFeat, through a temporary stage cache.
#![cfg(feature = "onnx")]

use crate::common;

use cgenreg::cache::Cache;
use cgenreg::dataset::Dataset;
use cgenreg::pipeline::study::{
    k_settings, markdown_table, prompt_settings, run_study, StudyKind, StudyProgress,
};
use cgenreg::pipeline::{RegisterParams, Registration, WfmSpec};

fn params() -> RegisterParams {
    common::demo_params(WfmSpec::Builtin)
}

fn demo() -> (Dataset, Vec<String>) {
    let ds = Dataset::load(&common::demo_manifest()).unwrap();
    let ids = ds.pairs().iter().map(|p| p.id.clone()).collect();
    (ds, ids)
}

#[test]
fn k_sweep_matches_direct_runs_and_skips_invalid_k() {
    let (ds, ids) = demo();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let p = params();
    let mut seen: Vec<StudyProgress> = Vec::new();
    let rep = run_study(
        &ds,
        &ids,
        &p,
        &k_settings(&[1, 2, 9]),
        Some(&cache),
        true,
        &mut |pr| seen.push(pr.clone()),
    )
    .unwrap();
    assert_eq!(rep.kind, StudyKind::K);
    assert_eq!(rep.rows.len(), 3);
    // K = 9 > L - m = 7: the whole setting is skipped with the pipeline's reason.
    let bad = &rep.rows[2];
    assert_eq!(bad.setting, "K = 9");
    assert!(
        bad.setting_skipped.as_deref().unwrap().contains("K = 9"),
        "{bad:?}"
    );
    assert_eq!(bad.pairs_run, 0);
    assert!(bad.rre_mean_deg.is_none() && bad.recall.is_none());
    // Progress counts only runnable (pair, setting) runs.
    assert_eq!(seen.len(), 2 * ids.len());
    assert_eq!(seen.last().unwrap().done, seen.last().unwrap().total);
    // Labelled with the generations' true source.
    assert_eq!(rep.backends.len(), 1);
    assert!(
        rep.backends[0].starts_with("builtin-depthshade-v1"),
        "{:?}",
        rep.backends
    );
    assert!(rep.vfm.starts_with("xfeat@"), "{}", rep.vfm);
    assert_eq!(rep.fusion, "NoisyAnd");
    let pair = ds.load_pair(&ids[0]).unwrap();
    for (row, k) in rep.rows[..2].iter().zip([1usize, 2]) {
        assert_eq!(row.k, k);
        assert_eq!(row.pairs_run, 1, "{row:?}");
        assert!(row.skipped.is_empty() && row.failed.is_empty(), "{row:?}");
        // Same numbers as the pipeline run directly at this K (in memory, no cache).
        let mut ib = p.image.clone().unwrap();
        ib.k = k;
        let q = RegisterParams {
            image: Some(ib),
            ..p.clone()
        };
        let direct = Registration::new(&q).run(&pair).unwrap();
        let m = direct.metrics.unwrap();
        let got = &row.per_pair[0];
        assert_eq!((got.rre_deg, got.rte_m), (m.rre_deg, m.rte_m), "K = {k}");
        assert_eq!(row.rre_mean_deg, Some(m.rre_deg));
        assert_eq!(row.rte_median_m, Some(m.rte_m));
        assert_eq!(row.recall, Some(if m.success { 1.0 } else { 0.0 }));
    }
    let table = markdown_table(&rep);
    assert!(table.contains("builtin-depthshade-v1") && table.contains("| K = 9 | – | all ("));
}

#[test]
fn prompt_study_has_four_categories_and_never_fakes_missing_generations() {
    let (ds, ids) = demo();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let p = params();
    let settings = prompt_settings(cgenreg::wfm::prompt::DEFAULT_PREFIX, None, None);

    // Nothing cached and generation not allowed: every pair is skipped, with the reason.
    let rep = run_study(&ds, &ids, &p, &settings, Some(&cache), false, &mut |_| {}).unwrap();
    assert_eq!(rep.kind, StudyKind::Prompt);
    assert_eq!(rep.rows.len(), 4);
    for r in &rep.rows {
        assert_eq!(r.pairs_run, 0);
        assert_eq!(r.skipped.len(), ids.len());
        assert!(
            r.skipped[0].reason.starts_with("generation not cached: "),
            "{r:?}"
        );
        assert!(r.rre_mean_deg.is_none());
    }
    assert!(rep.backends.is_empty());

    // With the built-in generator allowed to run: one generation per prompt, four rows.
    let rep = run_study(&ds, &ids, &p, &settings, Some(&cache), true, &mut |_| {}).unwrap();
    let labels: Vec<&str> = rep.rows.iter().map(|r| r.setting.as_str()).collect();
    assert_eq!(
        labels,
        ["scene-specific", "general", "minimal", "semantically-wrong"]
    );
    for r in &rep.rows {
        assert_eq!(r.pairs_run, 1, "{r:?}");
        assert!(r.rre_mean_deg.unwrap().is_finite());
        assert!(r.prompt.ends_with(
            cgenreg::wfm::PromptPreset::parse(&r.setting)
                .unwrap()
                .default_scene()
        ));
    }
    // One generation per prompt in the cache (the K sweep, by contrast, needs one per pair):
    // the built-in generator's selected views, one entry per side.
    let gens = std::fs::read_dir(dir.path().join("generation"))
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().is_dir())
        .count();
    assert_eq!(gens, 2 * 4);
}

/// A cancelled study stops before its next pair, keeps what ran and says so.
#[test]
fn a_cancelled_study_keeps_the_pairs_run_and_says_so() {
    use std::sync::atomic::{AtomicBool, Ordering};
    let (ds, ids) = demo();
    let pair = ds.load_pair(&ids[0]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    // The same pair under three ids: the flag goes up after the first one's run.
    let names: Vec<String> = (0..3).map(|i| format!("{}#{i}", ids[0])).collect();
    let cancel = AtomicBool::new(false);
    let rep = cgenreg::pipeline::study::run_study_with(
        &names,
        &mut |_| Ok(pair.clone()),
        &params(),
        &k_settings(&[2]),
        Some(&cache),
        &cgenreg::pipeline::Memo::default(),
        true,
        &mut |_| cancel.store(true, Ordering::Relaxed),
        Some(&cancel),
    )
    .unwrap();
    assert_eq!(rep.rows[0].pairs_run, 1, "{:?}", rep.rows[0]);
    assert!(rep.rows[0].failed.is_empty() && rep.rows[0].skipped.is_empty());
    assert!(
        rep.notes
            .iter()
            .any(|n| n.contains("cancelled after 1 of 3")),
        "{:?}",
        rep.notes
    );
}
