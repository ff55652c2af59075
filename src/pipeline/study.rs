//! Parameter studies of the paper: RRE/RTE against the number of views K (figure 6) and per
//! prompt category (figure 4). Every setting runs the same pairs with everything else fixed,
//! through the stage cache, so a K sweep re-uses one generation per pair (K only selects views)
//! and a prompt study needs one generation per prompt.
//!
//! Nothing is faked: a pair whose generation is not available (not cached and not generated,
//! or a cached Cosmos video made from another prompt) is skipped and counted with its reason;
//! a K that is invalid for L and m skips the whole setting. Every report carries the backend
//! ids of the generations that were actually used (from their provenance), the VFM and the
//! fusion mode.
//!
//! Aggregates of a row: mean / median RRE (degrees) and RTE (metres) over the pairs that ran;
//! registration recall with the metrics module's success rule (RRE <= 15 deg and RTE <= 0.3 m)
//! over the pairs that ran plus those that failed with an error (a failure counts as
//! unsuccessful, as in `bench`); skipped pairs enter no aggregate.

use super::memo::Memo;
use super::params::{ImageBranchParams, RegisterParams};
use super::register::Registration;
use crate::cache::Cache;
use crate::dataset::manifest::Dataset;
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::metrics::{PairMetrics, Summary};
use crate::wfm::{Prompt, PromptPreset};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Which parameter a study varies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum StudyKind {
    /// Views per side K (figure 6).
    K,
    /// Prompt category (figure 4).
    Prompt,
}

/// One setting of a study: everything else comes from the base parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum StudySetting {
    K(usize),
    Prompt { label: String, prompt: Prompt },
}

impl StudySetting {
    /// "K = 4", or the prompt's label ("scene-specific", "custom", ...).
    pub fn label(&self) -> String {
        match self {
            StudySetting::K(k) => format!("K = {k}"),
            StudySetting::Prompt { label, .. } => label.clone(),
        }
    }

    fn apply(&self, base: &ImageBranchParams) -> ImageBranchParams {
        let mut ib = base.clone();
        match self {
            StudySetting::K(k) => ib.k = *k,
            StudySetting::Prompt { prompt, .. } => ib.prompt = prompt.clone(),
        }
        ib
    }
}

/// The settings of a K sweep.
pub fn k_settings(ks: &[usize]) -> Vec<StudySetting> {
    ks.iter().map(|&k| StudySetting::K(k)).collect()
}

/// The paper's four prompt categories (presets, with `prefix` as the shared prefix; the
/// scene-specific one describes `scene_specific`, the data set's own scene, when it names one),
/// plus an optional custom scene description labelled "custom".
pub fn prompt_settings(
    prefix: &str,
    scene_specific: Option<&str>,
    custom_scene: Option<&str>,
) -> Vec<StudySetting> {
    let scene_specific = scene_specific.unwrap_or_default();
    let mut v: Vec<StudySetting> = PromptPreset::ALL
        .into_iter()
        .map(|p| StudySetting::Prompt {
            label: p.name().to_string(),
            prompt: Prompt::new(prefix, p.scene_text(scene_specific)),
        })
        .collect();
    if let Some(s) = custom_scene.filter(|s| !s.trim().is_empty()) {
        v.push(StudySetting::Prompt {
            label: "custom".into(),
            prompt: Prompt::new(prefix, s.trim()),
        });
    }
    v
}

/// One pair under one setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyPairResult {
    pub pair_id: String,
    pub rre_deg: f64,
    pub rte_m: f64,
    pub inlier_ratio: f64,
    pub success: bool,
    /// Backend id of the generation used (its provenance), e.g. "oracle".
    pub backend: String,
    pub time_s: f64,
}

/// A pair that did not enter the aggregates, and why.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PairNote {
    pub pair_id: String,
    pub reason: String,
}

/// The aggregate of one setting over the pairs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StudyRow {
    /// "K = 4", "scene-specific", ...
    pub setting: String,
    pub k: usize,
    /// The full prompt text of this setting.
    pub prompt: String,
    /// The whole setting was skipped (e.g. K invalid for L and m).
    pub setting_skipped: Option<String>,
    /// Pairs that ran and have metrics.
    pub pairs_run: usize,
    /// Pairs left out of every aggregate (generation not available, no ground truth).
    pub skipped: Vec<PairNote>,
    /// Pairs whose registration failed with an error: unsuccessful in the recall.
    pub failed: Vec<PairNote>,
    pub rre_mean_deg: Option<f64>,
    pub rre_median_deg: Option<f64>,
    pub rte_mean_m: Option<f64>,
    pub rte_median_m: Option<f64>,
    /// Successes / (pairs run + pairs failed); None when both are 0.
    pub recall: Option<f64>,
    pub per_pair: Vec<StudyPairResult>,
}

impl StudyRow {
    fn new(s: &StudySetting, ib: &ImageBranchParams) -> Self {
        StudyRow {
            setting: s.label(),
            k: ib.k,
            prompt: ib.prompt.text(),
            setting_skipped: None,
            pairs_run: 0,
            skipped: Vec::new(),
            failed: Vec::new(),
            rre_mean_deg: None,
            rre_median_deg: None,
            rte_mean_m: None,
            rte_median_m: None,
            recall: None,
            per_pair: Vec::new(),
        }
    }

    fn summarise(&mut self) {
        self.pairs_run = self.per_pair.len();
        let pm: Vec<PairMetrics> = self
            .per_pair
            .iter()
            .map(|p| PairMetrics {
                rre_deg: p.rre_deg,
                rte_m: p.rte_m,
                inlier_ratio: p.inlier_ratio,
                success: p.success,
                criterion: Default::default(),
                also: None,
            })
            .collect();
        let s = Summary::from_pairs(&pm);
        let some = |x: f64| (!pm.is_empty()).then_some(x);
        self.rre_mean_deg = some(s.rre_mean);
        self.rre_median_deg = some(s.rre_median);
        self.rte_mean_m = some(s.rte_mean);
        self.rte_median_m = some(s.rte_median);
        let n = pm.len() + self.failed.len();
        self.recall = (n > 0).then(|| pm.iter().filter(|p| p.success).count() as f64 / n as f64);
    }
}

/// A whole study, labelled with what produced it.
#[derive(Clone, Debug, Serialize)]
pub struct StudyReport {
    pub kind: StudyKind,
    /// Backend ids of the generations actually used (from provenance), in order of first use;
    /// empty when no pair ran.
    pub backends: Vec<String>,
    /// The configured backend, in words (shown when no pair ran).
    pub configured_backend: String,
    /// The VFM that described the views (e.g. "xfeat@… (onnx, native ORT …)"), else its name.
    pub vfm: String,
    pub fusion: String,
    pub pairs: Vec<String>,
    pub rows: Vec<StudyRow>,
    /// Things a reader must know (e.g. the oracle ignores prompts).
    pub notes: Vec<String>,
    pub params: RegisterParams,
}

impl StudyReport {
    /// "oracle · xfeat@… · fusion NoisyAnd" (plot titles, table headers).
    pub fn label(&self) -> String {
        let b = if self.backends.is_empty() {
            self.configured_backend.clone()
        } else {
            self.backends.join(", ")
        };
        format!("{b} · {} · fusion {}", self.vfm, self.fusion)
    }
}

/// Progress of a study: `done` of `total` (pair, setting) runs finished.
#[derive(Clone, Debug, PartialEq)]
pub struct StudyProgress {
    pub done: usize,
    pub total: usize,
    pub pair: String,
    pub setting: String,
}

/// The configured backend in words (the true ids come from provenance once a pair ran).
pub fn backend_label(spec: &super::params::WfmSpec) -> String {
    use super::params::WfmSpec;
    match spec {
        WfmSpec::Oracle => "oracle (real RGB)".into(),
        WfmSpec::Builtin => "builtin-depthshade-v1 (NOT a WFM)".into(),
        WfmSpec::Cached { dir, .. } => format!("cached:{}", dir.display()),
        WfmSpec::Cosmos { command, .. } => format!("cosmos:{}", command.join(" ")),
    }
}

/// Runs `settings` over the pairs `pair_ids` of `ds` (loaded once each); see
/// [`run_study_with`].
pub fn run_study(
    ds: &Dataset,
    pair_ids: &[String],
    params: &RegisterParams,
    settings: &[StudySetting],
    cache: Option<&Cache>,
    generate: bool,
    progress: &mut dyn FnMut(&StudyProgress),
) -> Result<StudyReport> {
    run_study_with(
        pair_ids,
        &mut |id| ds.load_pair(id),
        params,
        settings,
        cache,
        &Memo::default(),
        generate,
        progress,
        None,
    )
}

/// Runs every setting on every pair (pairs outer, so each pair is loaded once), with
/// `params.image` as the base of the image branch. `generate` false: a generation missing
/// from the cache is not produced and the pair is skipped for that setting. Errors only when
/// the study cannot start (no image branch, mixed setting kinds); per-pair problems become
/// skipped or failed entries.
// Every argument is an independent input of the study (pairs, loader, parameters, settings,
// cache, generation policy, progress, cancellation); a struct would only rename them.
#[allow(clippy::too_many_arguments)]
pub fn run_study_with(
    pair_ids: &[String],
    load: &mut dyn FnMut(&str) -> Result<ScanPair>,
    params: &RegisterParams,
    settings: &[StudySetting],
    cache: Option<&Cache>,
    memo: &Memo,
    generate: bool,
    progress: &mut dyn FnMut(&StudyProgress),
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<StudyReport> {
    let plan = plan_study(params, settings)?;
    let runnable = plan
        .rows
        .iter()
        .filter(|r| r.setting_skipped.is_none())
        .count();
    let total = runnable * pair_ids.len();
    let mut done = 0usize;
    let mut outcomes: Vec<(String, Vec<SettingOutcome>)> = Vec::new();
    let mut extra_notes = Vec::new();
    for id in pair_ids {
        // Checked between pairs: a cancelled study keeps the pairs already run, says so.
        if cancel.is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed)) {
            extra_notes.push(format!(
                "cancelled after {done} of {total} runs: the rows cover only the pairs run"
            ));
            break;
        }
        let pair = load(id).map_err(|e| e.to_string());
        let o = study_pair(
            &plan,
            pair.as_ref(),
            params,
            (cache, memo),
            generate,
            &mut |setting| {
                done += 1;
                progress(&StudyProgress {
                    done,
                    total,
                    pair: id.clone(),
                    setting: setting.to_string(),
                });
            },
        );
        outcomes.push((id.clone(), o));
    }
    let mut rep = assemble_study(&plan, params, pair_ids, &outcomes);
    rep.notes.extend(extra_notes);
    Ok(rep)
}

/// A study's settings resolved against the base parameters: one image-branch parameter set
/// and one (empty) row per setting, settings invalid for L and m marked skipped.
#[derive(Clone, Debug)]
pub struct StudyPlan {
    pub kind: StudyKind,
    pub base: ImageBranchParams,
    pub ibs: Vec<ImageBranchParams>,
    pub rows: Vec<StudyRow>,
    pub notes: Vec<String>,
}

/// What one pair gave under one setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "outcome", rename_all = "kebab-case")]
pub enum SettingOutcome {
    Ran {
        result: StudyPairResult,
        /// The VFM that described the views.
        vfm: String,
    },
    Skipped {
        reason: String,
    },
    Failed {
        reason: String,
    },
    /// The whole setting is skipped (invalid K for L and m).
    SettingSkipped,
}

/// Checks the settings and resolves them (see [`StudyPlan`]).
pub fn plan_study(params: &RegisterParams, settings: &[StudySetting]) -> Result<StudyPlan> {
    let base = params.image.as_ref().ok_or_else(|| {
        Error::Usage(
            "a study needs the image branch: choose a WFM backend (e.g. --wfm oracle or \
             --wfm builtin)"
                .into(),
        )
    })?;
    let kind = match settings.first() {
        Some(StudySetting::K(_)) => StudyKind::K,
        Some(StudySetting::Prompt { .. }) => StudyKind::Prompt,
        None => return Err(Error::Param("a study needs at least one setting".into())),
    };
    if settings
        .iter()
        .any(|s| matches!(s, StudySetting::K(_)) != (kind == StudyKind::K))
    {
        return Err(Error::Param(
            "a study varies one parameter: K values and prompts cannot be mixed".into(),
        ));
    }
    let ibs: Vec<ImageBranchParams> = settings.iter().map(|s| s.apply(base)).collect();
    let rows: Vec<StudyRow> = settings
        .iter()
        .zip(&ibs)
        .map(|(s, ib)| {
            let mut r = StudyRow::new(s, ib);
            // Invalid K / m for L: the pipeline would refuse every pair the same way.
            if let Err(e) = crate::wfm::select_views(
                2 * ib.frames_per_fragment,
                ib.frames_per_fragment,
                ib.margin,
                ib.k,
            ) {
                r.setting_skipped = Some(e.to_string());
            }
            r
        })
        .collect();
    let mut notes = Vec::new();
    if kind == StudyKind::Prompt && matches!(base.backend, super::params::WfmSpec::Oracle) {
        notes.push(
            "the oracle backend ignores the prompt: every category uses the same real RGB \
             frames"
                .to_string(),
        );
    }
    Ok(StudyPlan {
        kind,
        base: base.clone(),
        ibs,
        rows,
        notes,
    })
}

/// Runs every setting of `plan` on one pair (`pair` is the loaded pair or why it could not
/// be loaded); `on_setting` is called after each runnable setting with its label.
pub fn study_pair(
    plan: &StudyPlan,
    pair: std::result::Result<&ScanPair, &String>,
    params: &RegisterParams,
    (cache, memo): (Option<&Cache>, &Memo),
    generate: bool,
    on_setting: &mut dyn FnMut(&str),
) -> Vec<SettingOutcome> {
    plan.rows
        .iter()
        .zip(&plan.ibs)
        .map(|(row, ib)| {
            if row.setting_skipped.is_some() {
                return SettingOutcome::SettingSkipped;
            }
            let o = match pair {
                Ok(pair) => run_one(pair, params, ib, (cache, memo), generate, plan.kind),
                Err(e) => SettingOutcome::Failed {
                    reason: format!("loading the pair: {e}"),
                },
            };
            on_setting(&row.setting);
            o
        })
        .collect()
}

/// The report of `plan` from the pairs' outcomes (in the order given, which is the order
/// the backends are listed in).
pub fn assemble_study(
    plan: &StudyPlan,
    params: &RegisterParams,
    pair_ids: &[String],
    outcomes: &[(String, Vec<SettingOutcome>)],
) -> StudyReport {
    let mut rows = plan.rows.clone();
    let mut backends: Vec<String> = Vec::new();
    let mut vfm: Option<String> = None;
    for (id, os) in outcomes {
        for (row, o) in rows.iter_mut().zip(os) {
            let note = |reason: &String| PairNote {
                pair_id: id.clone(),
                reason: reason.clone(),
            };
            match o {
                SettingOutcome::Ran { result, vfm: v } => {
                    if !backends.contains(&result.backend) {
                        backends.push(result.backend.clone());
                    }
                    if vfm.is_none() {
                        vfm = Some(v.clone());
                    }
                    row.per_pair.push(result.clone());
                }
                SettingOutcome::Skipped { reason } => row.skipped.push(note(reason)),
                SettingOutcome::Failed { reason } => row.failed.push(note(reason)),
                SettingOutcome::SettingSkipped => {}
            }
        }
    }
    for r in &mut rows {
        r.summarise();
    }
    StudyReport {
        kind: plan.kind,
        backends,
        configured_backend: backend_label(&plan.base.backend),
        vfm: vfm.unwrap_or_else(|| plan.base.vfm.name().to_string()),
        fusion: format!("{:?}", params.fusion.mode),
        pairs: pair_ids.to_vec(),
        rows,
        notes: plan.notes.clone(),
        params: params.clone(),
    }
}

fn run_one(
    pair: &ScanPair,
    params: &RegisterParams,
    ib: &ImageBranchParams,
    (cache, memo): (Option<&Cache>, &Memo),
    generate: bool,
    kind: StudyKind,
) -> SettingOutcome {
    let skipped = |reason: String| SettingOutcome::Skipped { reason };
    let failed = |reason: String| SettingOutcome::Failed { reason };
    if pair.gt_target_from_source.is_none() {
        return skipped("no ground truth: RRE/RTE cannot be measured".into());
    }
    let t = Instant::now();
    // the setting's image branch on the run's other parameters
    let params = RegisterParams {
        image: Some(ib.clone()),
        ..params.clone()
    };
    let reg = Registration {
        cache,
        memo: Some(memo),
        generate,
        ..Registration::new(&params)
    };
    let r = match crate::error::catch_panic(|| reg.run(pair)) {
        Ok(r) => r,
        Err(e @ Error::GenerationNotCached { .. }) => return skipped(e.to_string()),
        Err(e) => return failed(e.to_string()),
    };
    let Some(img) = r.image.as_ref() else {
        return failed("the image branch produced no output".into());
    };
    let prov = &img.provenance;
    // A cached Cosmos video keeps the prompt it was made with: in a prompt study, frames from
    // another prompt would be counted under the wrong category.
    let used = prov.prompt.trim();
    if kind == StudyKind::Prompt && !used.is_empty() && used != ib.prompt.text().trim() {
        return skipped(format!(
            "the {} frames were generated with another prompt (\"{}\")",
            prov.backend,
            used.chars().take(60).collect::<String>()
        ));
    }
    let Some(m) = r.metrics else {
        return skipped("no metrics (no ground truth)".into());
    };
    SettingOutcome::Ran {
        result: StudyPairResult {
            pair_id: pair.id.clone(),
            rre_deg: m.rre_deg,
            rte_m: m.rte_m,
            inlier_ratio: m.inlier_ratio,
            success: m.success,
            backend: prov.backend.clone(),
            time_s: t.elapsed().as_secs_f64(),
        },
        vfm: img.vfm.clone(),
    }
}

/// Parses "1,2,4,8" (spaces allowed) into K values; a bad entry is a clear error.
pub fn parse_ks(s: &str) -> Result<Vec<usize>> {
    let ks: Vec<usize> = s
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.parse::<usize>().map_err(|_| {
                Error::Param(format!(
                    "K list {s:?}: {t:?} is not a whole number (expected e.g. 1,2,4,8)"
                ))
            })
        })
        .collect::<Result<_>>()?;
    if ks.is_empty() {
        return Err(Error::Param(format!(
            "K list {s:?} is empty (expected e.g. 1,2,4,8)"
        )));
    }
    Ok(ks)
}

/// The report as a Markdown table (the CLI prints it; docs/studies.md quotes it).
pub fn markdown_table(rep: &StudyReport) -> String {
    let mut out = format!(
        "{} study · backend {} · VFM {} · fusion {} · {} pairs\n\n",
        match rep.kind {
            StudyKind::K => "K",
            StudyKind::Prompt => "Prompt",
        },
        if rep.backends.is_empty() {
            format!("{} (no pair ran)", rep.configured_backend)
        } else {
            rep.backends.join(", ")
        },
        rep.vfm,
        rep.fusion,
        rep.pairs.len()
    );
    out.push_str(
        "| setting | run | skipped | failed | RR % | RRE mean° | RRE med° | RTE mean cm | RTE med cm |\n",
    );
    out.push_str("|---|---|---|---|---|---|---|---|---|\n");
    let f = |x: Option<f64>, scale: f64| x.map_or("–".into(), |v| format!("{:.2}", v * scale));
    for r in &rep.rows {
        if let Some(why) = &r.setting_skipped {
            out.push_str(&format!(
                "| {} | – | all ({why}) | – | – | – | – | – | – |\n",
                r.setting
            ));
            continue;
        }
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.setting,
            r.pairs_run,
            r.skipped.len(),
            r.failed.len(),
            r.recall.map_or("–".into(), |v| format!("{:.1}", 100.0 * v)),
            f(r.rre_mean_deg, 1.0),
            f(r.rre_median_deg, 1.0),
            f(r.rte_mean_m, 100.0),
            f(r.rte_median_m, 100.0),
        ));
    }
    for n in &rep.notes {
        out.push_str(&format!("\nnote: {n}\n"));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ks_parse_and_reject_garbage() {
        assert_eq!(parse_ks("1, 2,4,8").unwrap(), vec![1, 2, 4, 8]);
        assert!(parse_ks("1,x").unwrap_err().to_string().contains("\"x\""));
        assert!(parse_ks(" , ").is_err());
    }

    #[test]
    fn prompt_settings_are_the_four_categories_plus_custom() {
        let s = prompt_settings("P:", None, Some("a barn"));
        let labels: Vec<String> = s.iter().map(|x| x.label()).collect();
        assert_eq!(
            labels,
            [
                "scene-specific",
                "general",
                "minimal",
                "semantically-wrong",
                "custom"
            ]
        );
        match &s[4] {
            StudySetting::Prompt { prompt, .. } => assert_eq!(prompt.text(), "P: a barn"),
            _ => unreachable!(),
        }
        assert_eq!(prompt_settings("P:", None, Some("  ")).len(), 4);
        // a data set's own scene is its scene-specific category
        match &prompt_settings("P:", Some("a red barn"), None)[0] {
            StudySetting::Prompt { prompt, label } => {
                assert_eq!(
                    (label.as_str(), prompt.text().as_str()),
                    ("scene-specific", "P: a red barn")
                )
            }
            _ => unreachable!(),
        }
    }

    #[test]
    fn study_without_image_branch_or_mixed_kinds_is_an_error() {
        let p = RegisterParams::default();
        let e = run_study_with(
            &[],
            &mut |_| unreachable!(),
            &p,
            &k_settings(&[1]),
            None,
            &Memo::default(),
            true,
            &mut |_| {},
            None,
        )
        .unwrap_err();
        assert!(e.to_string().contains("image branch"), "{e}");
        let p = RegisterParams {
            image: Some(ImageBranchParams::default()),
            ..Default::default()
        };
        let mut mixed = k_settings(&[1]);
        mixed.extend(prompt_settings("", None, None));
        let e = run_study_with(
            &[],
            &mut |_| unreachable!(),
            &p,
            &mixed,
            None,
            &Memo::default(),
            true,
            &mut |_| {},
            None,
        )
        .unwrap_err();
        assert!(e.to_string().contains("cannot be mixed"), "{e}");
    }

    #[test]
    fn row_summary_counts_failures_in_recall_only() {
        let s = StudySetting::K(2);
        let mut r = StudyRow::new(&s, &ImageBranchParams::default());
        for (i, (rre, rte, ok)) in [(1.0, 0.02, true), (30.0, 0.5, false), (3.0, 0.04, true)]
            .into_iter()
            .enumerate()
        {
            r.per_pair.push(StudyPairResult {
                pair_id: format!("p{i}"),
                rre_deg: rre,
                rte_m: rte,
                inlier_ratio: 0.5,
                success: ok,
                backend: "b".into(),
                time_s: 0.0,
            });
        }
        r.failed.push(PairNote {
            pair_id: "p3".into(),
            reason: "x".into(),
        });
        r.skipped.push(PairNote {
            pair_id: "p4".into(),
            reason: "y".into(),
        });
        r.summarise();
        assert_eq!(r.pairs_run, 3);
        assert!((r.rre_mean_deg.unwrap() - 34.0 / 3.0).abs() < 1e-12);
        assert_eq!(r.rre_median_deg, Some(3.0));
        assert!((r.rte_median_m.unwrap() - 0.04).abs() < 1e-12);
        assert_eq!(r.recall, Some(0.5));
    }
}
