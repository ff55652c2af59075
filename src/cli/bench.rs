//! `cgenreg bench`: every selected pair of a manifest, the paper-style table, per-pair JSON.
//! Sharded (`--shard I/N`) and resumable: the JSON is rewritten atomically after every pair
//! (see `pipeline::shard`), a pair that fails (error or panic) is recorded with its reason
//! and the run goes on.

use super::args::{ImageArgs, PipelineArgs};
use crate::cli::args::ManifestSettings;
use crate::dataset::fragment_cache::pair_summary;
use crate::dataset::manifest::{Dataset, PairSpec};
use crate::dataset::repose::repose_motion;
use crate::error::{Error, Result};
use crate::metrics::field::rmse_counts;
use crate::metrics::{rmse_3dmatch, SuccessCriterion};
use crate::pipeline::shard::{
    run_pending, stage_totals, PairRecord, Progress, ResumeMode, RunIdentity, Shard, StageTime,
    DONE, FAILED,
};
use crate::pipeline::{Memo, Registration};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    pub pairs: PairsArgs,
    /// List the pairs and exit.
    #[arg(long)]
    pub list: bool,
    /// Write per-pair results and a summary as JSON, rewritten after every pair.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Turn every pair's source by a seeded random rotation about its origin first (uniform on
    /// SO(3); its frames and the GT turn with it; the origin, its viewpoint, stays): the same
    /// problems in other coordinate frames, to see how much of a result is the frame.
    #[arg(long)]
    pub repose_seed: Option<u64>,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

/// The pairs a run covers, shared by `bench`, `study` and `generate`.
#[derive(Args, Debug, Clone)]
pub struct PairsArgs {
    /// Dataset manifest (TOML).
    pub manifest: PathBuf,
    /// Only pairs of this split (e.g. 3DMatch, 3DLoMatch); default all, reported per split.
    #[arg(long)]
    pub split: Option<String>,
    /// Only the first N pairs.
    #[arg(long)]
    pub limit: Option<usize>,
}

impl PairsArgs {
    /// The dataset, with the fragment cache the image options name.
    pub fn dataset(&self, image: &ImageArgs) -> Result<Dataset> {
        Ok(Dataset::load(&self.manifest)?.with_fragment_cache(image.fragment_cache()?))
    }

    /// The selected pairs; none is an error naming the manifest.
    pub fn select<'a>(&self, ds: &'a Dataset) -> Result<Vec<&'a PairSpec>> {
        selection(ds, &self.manifest, self.split.as_deref(), self.limit)
    }
}

/// Sharding and resuming, shared by `bench`, `study` and `generate`.
#[derive(Args, Debug, Clone, Default)]
pub struct RunArgs {
    /// Run only shard I of N (0 <= I < N): the selected pairs at positions p with
    /// p mod N == I. Merge the shards' JSONs with `cgenreg merge`.
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Keep the pairs an existing --json output already has (the default; it must have been
    /// written with the same parameters and binary).
    #[arg(long, conflicts_with = "no_resume")]
    pub resume: bool,
    /// Ignore an existing --json output and run every pair.
    #[arg(long)]
    pub no_resume: bool,
    /// Replace an existing --json file even when it is not a cgenreg run file.
    #[arg(long)]
    pub force: bool,
}

impl RunArgs {
    pub fn shard(&self) -> Shard {
        self.shard.unwrap_or(Shard::ALL)
    }
    /// Checks the --json output before any work: a new path or a regular file that is a run
    /// file (or anything regular with --force); never a link, device, FIFO or folder.
    pub fn check_output(&self, json: Option<&std::path::Path>) -> Result<()> {
        match json {
            Some(p) => {
                crate::io::output::prepare(p, crate::io::output::OutputKind::RunJson, self.force)
            }
            None => Ok(()),
        }
    }
    pub fn mode(&self) -> ResumeMode {
        if self.no_resume {
            ResumeMode::Restart
        } else {
            ResumeMode::Resume
        }
    }
}

use crate::metrics::FieldSummary;
pub use crate::report::bench_file::{
    bench_json, field_summaries, rows_of, summarise, PairRow, SplitSummary,
};

/// The paper-style table of `summaries`, with the success criterion it counts by.
pub fn print_table(summaries: &[SplitSummary]) {
    let mut crits: Vec<String> = summaries.iter().map(|x| x.criterion.label()).collect();
    crits.dedup();
    outln!("RR: registration recall, success = {}", crits.join(" / "));
    let also = summaries.iter().find_map(|x| x.also.map(|(c, _)| c));
    if let Some(c) = also {
        outln!("RR {}: success = {}", c.short(), c.label());
    }
    let also_head = also.map_or(String::new(), |c| format!(" RR {} % |", c.short()));
    outln!(
        "| split | pairs | RR % |{also_head} RA@5° | RA@10° | RA@45° | RRE mean° | RRE med° | TA@5cm | TA@10cm | TA@25cm | RTE mean cm | RTE med cm | s/pair |"
    );
    outln!(
        "|---|---|---|{}---|---|---|---|---|---|---|---|---|---|---|",
        if also.is_some() { "---|" } else { "" }
    );
    let num = |v: f64, scale: f64| {
        if v.is_finite() {
            format!("{:.2}", scale * v)
        } else {
            "–".to_string()
        }
    };
    for x in summaries {
        let s = &x.summary;
        let also_cell = match (also, x.also) {
            (Some(_), Some((_, r))) => format!(" {:.1} |", 100.0 * r),
            (Some(_), None) => " - |".to_string(),
            (None, _) => String::new(),
        };
        outln!(
            "| {} | {} | {:.1} |{also_cell} {:.1} | {:.1} | {:.1} | {} | {} | {:.1} | {:.1} | {:.1} | {} | {} | {:.3} |",
            x.split,
            s.n,
            100.0 * s.recall,
            100.0 * s.rot_acc_5,
            100.0 * s.rot_acc_10,
            100.0 * s.rot_acc_45,
            num(s.rre_mean, 1.0),
            num(s.rre_median, 1.0),
            100.0 * s.trans_acc_5cm,
            100.0 * s.trans_acc_10cm,
            100.0 * s.trans_acc_25cm,
            num(s.rte_mean, 100.0),
            num(s.rte_median, 100.0),
            x.time_per_pair_s
        );
    }
    let errors: usize = summaries.iter().map(|x| x.errors).sum();
    if errors > 0 {
        outln!(
            "{errors} pair(s) ran with an error: counted as failures in RR, RA and TA; the RRE and \
             RTE means and medians are over the pairs with a pose"
        );
    }
}

/// The paper-style table (SC2-PCR's and GeoTransformer's layout): per benchmark and scene, then
/// pooled per benchmark, the recall under the run's criterion (and its second one), the
/// official 3DMatch recall (RMSE < 0.2 m, over the pairs it counts) where the manifest gives
/// gt.info, and the mean / median RE and TE over the registered pairs.
pub fn print_field_table(rows: &[FieldSummary]) {
    let Some(first) = rows.first() else { return };
    let also = rows.iter().find_map(|r| r.also.map(|(c, _)| c));
    let rmse = rows.iter().any(|r| r.rmse_recall.is_some());
    outln!(
        "Per benchmark and scene: RR = registration recall at {}{}{}; RE / TE over the registered pairs",
        first.criterion.label(),
        also.map_or(String::new(), |c| format!(", RR {} at {}", c.short(), c.label())),
        if rmse {
            "; RR RMSE = the official 3DMatch recall, RMSE < 0.2 m over gt.info, on the pairs of \
             non-consecutive fragments"
        } else {
            ""
        }
    );
    outln!(
        "| benchmark | scene | pairs | RR % |{}{} RE mean ° | RE med ° | TE mean cm | TE med cm |",
        also.map_or(String::new(), |c| format!(" RR {} % |", c.short())),
        if rmse { " RR RMSE % (pairs) |" } else { "" }
    );
    outln!(
        "|---|---|---|---|{}{}---|---|---|---|",
        if also.is_some() { "---|" } else { "" },
        if rmse { "---|" } else { "" }
    );
    let num = |v: f64, scale: f64| {
        if v.is_finite() {
            format!("{:.2}", scale * v)
        } else {
            "–".to_string()
        }
    };
    for r in rows {
        let also_cell = match (also, r.also) {
            (Some(_), Some((_, f))) => format!(" {:.1} |", 100.0 * f),
            (Some(_), None) => " - |".into(),
            (None, _) => String::new(),
        };
        let rmse_cell = match (rmse, r.rmse_recall) {
            (true, Some(f)) => format!(" {:.1} ({}) |", 100.0 * f, r.rmse_pairs),
            (true, None) => " - |".into(),
            (false, _) => String::new(),
        };
        outln!(
            "| {} | {} | {} | {:.1} |{also_cell}{rmse_cell} {} | {} | {} | {} |",
            r.benchmark,
            r.scene.as_deref().unwrap_or("all"),
            r.pairs,
            100.0 * r.rr,
            num(r.re_mean_deg, 1.0),
            num(r.re_median_deg, 1.0),
            num(r.te_mean_m, 100.0),
            num(r.te_median_m, 100.0),
        );
    }
}

/// One line per pair: the GT distance, the errors and the verdict under each criterion.
pub fn print_pair_table(rows: &[PairRow]) {
    let crit = rows
        .iter()
        .find_map(|r| r.criterion)
        .unwrap_or(SuccessCriterion::THREEDMATCH);
    let also = rows.iter().find_map(|r| r.also.map(|j| j.criterion));
    let opt = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |x| format!("{x:.d$}"));
    let mark = |b: Option<bool>| match b {
        Some(true) => "yes",
        Some(false) => "no",
        None => "-",
    };
    outln!(
        "| pair | distance m | RRE ° | RTE m | success {} |{} s |",
        crit.short(),
        also.map_or(String::new(), |c| format!(" success {} |", c.short()))
    );
    outln!(
        "|---|---|---|---|---|{}---|",
        if also.is_some() { "---|" } else { "" }
    );
    for r in rows {
        let also_cell = match also {
            Some(_) => format!(
                " {} |",
                mark(r.also.map(|j| j.success).or(r.success.and(Some(false))))
            ),
            None => String::new(),
        };
        outln!(
            "| {} | {} | {} | {} | {} |{also_cell} {:.2} |{}",
            r.id,
            opt(r.gt_distance_m, 1),
            opt(r.rre_deg, 2),
            opt(r.rte_m, 3),
            mark(r.success),
            r.time_s,
            r.error
                .as_deref()
                .map_or(String::new(), |e| format!(" error: {e}"))
        );
    }
}

/// The stage table: total seconds per stage, pairs cached / computed.
pub fn print_stage_table<'a>(records: impl IntoIterator<Item = &'a PairRecord>) {
    outln!("| stage | total s | cached | computed |");
    outln!("|---|---|---|---|");
    for (name, ms, computed, cached) in stage_totals(records) {
        outln!("| {name} | {:.2} | {cached} | {computed} |", ms / 1e3);
    }
}

/// A log line: on the progress bar when it is drawn, else on stderr (Slurm logs).
pub fn log_line(bar: &indicatif::ProgressBar, s: &str) {
    if bar.is_hidden() {
        eprintln!("{s}");
    } else {
        bar.println(s);
    }
}

pub fn progress_bar(len: usize) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed}<{eta}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

/// The selected pairs and the run identity of a `command` over a manifest.
pub fn selection<'a>(
    ds: &'a Dataset,
    manifest: &std::path::Path,
    split: Option<&str>,
    limit: Option<usize>,
) -> Result<Vec<&'a PairSpec>> {
    let specs = ds.select_pairs(split, limit);
    if specs.is_empty() {
        return Err(Error::Missing(format!(
            "{}: no pairs selected",
            manifest.display()
        )));
    }
    Ok(specs)
}

/// Whether the official 3DMatch recall counts a pair: a gt.info entry of fragments that are not
/// consecutive, in the data's own frame (gt.info does not hold for a re-posed source).
pub(super) fn rmse_counted(spec: &PairSpec, reposed: bool) -> bool {
    !reposed
        && spec
            .gt_info
            .as_ref()
            .is_some_and(|i| rmse_counts(i.target, i.source))
}

pub fn run(a: BenchArgs) -> Result<()> {
    let ds = a.pairs.dataset(&a.image)?;
    if a.list {
        for p in ds.select_pairs(a.pairs.split.as_deref(), a.pairs.limit) {
            outln!("{}\t{}", p.id, p.split);
        }
        return Ok(());
    }
    a.run.check_output(a.json.as_deref())?;
    let specs = a.pairs.select(&ds)?;
    let (params, cache) = a
        .image
        .params_and_cache_for(&a.pipeline, &ManifestSettings::of(&ds))?;
    // a pair that names a preset other than the data set's runs under it (unless --preset)
    let pair_params = |spec: &PairSpec| -> Result<Option<crate::pipeline::RegisterParams>> {
        match spec.preset {
            Some(pp) if a.pipeline.preset.is_none() && Some(pp) != ds.preset => a
                .image
                .params_and_cache_for(
                    &a.pipeline,
                    &ManifestSettings {
                        preset: Some(pp),
                        ..ManifestSettings::of(&ds)
                    },
                )
                .map(|(p, _)| Some(p)),
            _ => Ok(None),
        }
    };
    let shard = a.run.shard();
    // the thresholds as used (a distance that follows the voxel as its value)
    let mut params_json = serde_json::to_value(params.resolved())
        .map_err(|e| Error::Encode(format!("serialising parameters: {e}")))?;
    // part of the run's identity: a resumed run never mixes two frames
    if let (Some(seed), Some(o)) = (a.repose_seed, params_json.as_object_mut()) {
        o.insert("repose_seed".into(), seed.into());
    }
    let identity = RunIdentity::new(
        "bench",
        &a.pairs.manifest,
        a.pairs.split.as_deref(),
        a.pairs.limit,
        params_json,
        shard.count,
        specs.iter().map(|s| s.id.clone()).collect(),
    )?;
    let (mut progress, message) =
        Progress::start(identity, shard, a.json.as_deref(), a.run.mode())?;
    if let Some(m) = message {
        eprintln!("{m}");
    }
    if shard.count > 1 {
        eprintln!(
            "shard {shard}: {} of the {} selected pairs",
            progress.positions.len(),
            specs.len()
        );
    }
    let mut warnings = 0usize;
    let bar = progress_bar(progress.positions.len());
    bar.set_position((progress.positions.len() - progress.pending().len()) as u64);
    // one memo for the run: the VFM model loads once, each input file is hashed once
    let memo = Memo::default();
    let mut run_pair = |pos: usize, id: &str| -> Result<PairRecord> {
        let spec = specs[pos];
        bar.set_message(id.to_string());
        let t = std::time::Instant::now();
        let res = ds.load_pair_status(&spec.id).and_then(|(pair, st)| {
            let pair = match a.repose_seed {
                Some(seed) => {
                    pair.with_source_moved(&repose_motion(seed, &spec.id), params.image.is_some())?
                }
                None => pair,
            };
            let load_ms = t.elapsed().as_secs_f64() * 1e3;
            let (hit, rebuilt) = pair_summary(&st);
            for why in rebuilt {
                log_line(
                    &bar,
                    &format!("{}: warning: fragment cache: {why}", spec.id),
                );
                warnings += 1;
            }
            let loaded = hit == Some(true);
            let own = pair_params(spec)?;
            let p = own.as_ref().unwrap_or(&params);
            let mut r = Registration::new(p)
                .cache(cache.as_ref())
                .memo(&memo)
                .run(&pair)?;
            r.timings.insert(
                0,
                crate::pipeline::StageTiming {
                    name: None,
                    stage: "load pair".into(),
                    ms: load_ms,
                    status: if loaded { "cached" } else { "computed" }.into(),
                },
            );
            Ok(r)
        });
        let time_s = t.elapsed().as_secs_f64();
        bar.inc(1);
        let rmse_counted = rmse_counted(spec, a.repose_seed.is_some());
        let (row, stages, status) = match res {
            Ok(r) => {
                for w in &r.warnings {
                    if w.contains("corrupt") || w.contains("could not write cache") {
                        log_line(&bar, &format!("{}: warning: {w}", spec.id));
                        warnings += 1;
                    }
                }
                let stages = r
                    .timings
                    .iter()
                    .map(|t| StageTime {
                        stage: t.stage.clone(),
                        ms: t.ms,
                        status: t.status.clone(),
                    })
                    .collect();
                let row = PairRow {
                    id: spec.id.clone(),
                    split: spec.split.clone(),
                    source: r.source_name.clone(),
                    target: r.target_name.clone(),
                    rre_deg: r.metrics.as_ref().map(|m| m.rre_deg),
                    rte_m: r.metrics.as_ref().map(|m| m.rte_m),
                    inlier_ratio: r.metrics.as_ref().map(|m| m.inlier_ratio),
                    success: r.metrics.as_ref().map(|m| m.success),
                    time_s,
                    error: None,
                    criterion: r.metrics.as_ref().map(|m| m.criterion),
                    also: r.metrics.as_ref().and_then(|m| m.also),
                    gt_distance_m: spec
                        .gt_target_from_source
                        .as_ref()
                        .map(|t| t.translation.vector.norm()),
                    fusion: r.fusion_provenance(),
                    scales: r.scales.as_ref().map(|s| s.provenance()),
                    scene: spec.scene.clone(),
                    rmse_counted,
                    rmse_m: match (&spec.gt_info, &spec.gt_target_from_source) {
                        (Some(info), Some(gt)) if rmse_counted => {
                            Some(rmse_3dmatch(&r.estimate, gt, &info.information))
                        }
                        _ => None,
                    },
                };
                for line in [r.fusion_provenance(), row.scales.clone()]
                    .into_iter()
                    .flatten()
                {
                    log_line(&bar, &format!("{}: {line}", spec.id));
                }
                (row, stages, DONE)
            }
            Err(e) => (
                PairRow {
                    scene: spec.scene.clone(),
                    rmse_counted,
                    ..PairRow::failed(&spec.id, &spec.split, &e.to_string(), time_s)
                },
                Vec::new(),
                FAILED,
            ),
        };
        Ok(PairRecord {
            id: spec.id.clone(),
            status: status.into(),
            error: row.error.clone(),
            time_s,
            stages,
            result: serde_json::to_value(&row)
                .map_err(|e| Error::Encode(format!("serialising a row: {e}")))?,
        })
    };
    let failed_result = |pos: usize, why: &str| {
        let spec = specs[pos];
        serde_json::to_value(PairRow {
            scene: spec.scene.clone(),
            rmse_counted: rmse_counted(spec, a.repose_seed.is_some()),
            ..PairRow::failed(&spec.id, &spec.split, why, 0.0)
        })
        .unwrap_or_default()
    };
    let written = run_pending(
        &mut progress,
        &bench_json,
        &mut run_pair,
        &failed_result,
        &mut |l| log_line(&bar, l),
    );
    bar.finish_and_clear();

    let file = progress.run_file();
    let rows = rows_of(&file)?;
    print_table(&summarise(&rows));
    outln!();
    print_field_table(&field_summaries(&rows));
    outln!();
    print_pair_table(&rows);
    outln!();
    print_stage_table(&file.records);
    let (n_cached, n_computed) = stage_totals(&file.records)
        .iter()
        .fold((0, 0), |(c, n), s| (c + s.3, n + s.2));
    outln!(
        "cache ({}): {n_cached} stage results were cache hits, {n_computed} were computed{}",
        cache
            .as_ref()
            .map(|c| c.root().display().to_string())
            .or_else(|| ds
                .fragment_cache
                .as_ref()
                .map(|c| format!("fragments only: {}", c.root().display())))
            .unwrap_or_else(|| "off".into()),
        if warnings > 0 {
            format!("; {warnings} cache problems reported above")
        } else {
            String::new()
        }
    );
    let failed: Vec<&PairRecord> = file.records.iter().filter(|r| r.status == FAILED).collect();
    if !failed.is_empty() {
        eprintln!("{} of {} pairs failed:", failed.len(), file.records.len());
        for r in &failed {
            eprintln!("  {}: {}", r.id, r.error.as_deref().unwrap_or(""));
        }
    }
    written?;
    if let Some(path) = &a.json {
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
