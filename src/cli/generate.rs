//! `cgenreg generate`: fills the shared stage cache with the expensive stages of the selected
//! pairs (depth video, the configured generator, the VFM descriptors and lifting), sharded and
//! resumable like `bench`, so that a later `bench` or `study` with the same image-branch
//! options reads every generation from the cache.
//!
//! Each pair runs the image branch through the cache with generation on (the same code as
//! `register` and `bench`, so the cache keys are the same); the cheap tail (similarity, fusion,
//! SC2-PCR: about a second against minutes of generation for a world model) runs too, and its
//! metrics are kept in the output as a by-product.

use super::args::{ImageArgs, PipelineArgs};
use super::bench::{log_line, progress_bar, PairsArgs, RunArgs};
use crate::cli::args::ManifestSettings;
use crate::dataset::manifest::Dataset;
use crate::error::{Error, Result};
use crate::pipeline::shard::{
    run_pending, stage_totals, PairRecord, Progress, RunIdentity, StageTime, DONE,
};
use crate::report::generate_file::generate_json;
use clap::Args;
use serde_json::json;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct GenerateArgs {
    #[command(flatten)]
    pub pairs: PairsArgs,
    /// Record per-pair stage times and cache status as JSON, rewritten after every pair
    /// (resumable; `cgenreg status` reads it).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// With --wfm cosmos, run the command once per pair (its own job folder) instead of once
    /// for all of the shard's missing generations (one batch JSONL, as the reference does).
    #[arg(long)]
    pub no_batch: bool,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

pub fn run(a: GenerateArgs) -> Result<()> {
    if a.image.wfm.is_none() {
        return Err(Error::Usage(
            "generate fills the cache of the image branch: pass --wfm builtin, oracle, cached or \
             cosmos"
                .into(),
        ));
    }
    if a.image.no_cache {
        return Err(Error::Usage(
            "generate writes into the stage cache: --no-cache makes no sense here".into(),
        ));
    }
    a.run.check_output(a.json.as_deref())?;
    let ds = a.pairs.dataset(&a.image)?;
    let specs = a.pairs.select(&ds)?;
    let (params, cache) = a
        .image
        .params_and_cache_for(&a.pipeline, &ManifestSettings::of(&ds))?;
    let Some(ib) = params.image.clone() else {
        return Err(Error::Missing("no image branch".into()));
    };
    let shard = a.run.shard();
    let identity = RunIdentity::new(
        "generate",
        &a.pairs.manifest,
        a.pairs.split.as_deref(),
        a.pairs.limit,
        serde_json::to_value(&params)
            .map_err(|e| Error::Encode(format!("serialising parameters: {e}")))?,
        shard.count,
        specs.iter().map(|s| s.id.clone()).collect(),
    )?;
    let (mut progress, message) =
        Progress::start(identity, shard, a.json.as_deref(), a.run.mode())?;
    if let Some(m) = message {
        eprintln!("{m}");
    }
    // Cosmos loads a 7B model per run: the shard's missing generations go in one batch, then
    // the per-pair pass below reads them from the cache.
    let batched = matches!(ib.backend, crate::pipeline::WfmSpec::Cosmos { .. }) && !a.no_batch;
    let mut batch_errors: std::collections::HashMap<String, String> = Default::default();
    if batched {
        if let Some(c) = cache.as_ref() {
            let ids: Vec<String> = progress
                .pending()
                .iter()
                .map(|&p| progress.id(p).to_string())
                .collect();
            batch_errors = generate_batch(&ds, &ids, &ib, c);
        }
    }
    let bar = progress_bar(progress.positions.len());
    // one memo for the run: each pair's VFM model loads once
    let memo = crate::pipeline::Memo::default();
    let mut run_pair = |pos: usize, id: &str| -> Result<PairRecord> {
        if let Some(e) = batch_errors.get(id) {
            bar.inc(1);
            return Err(Error::Invalid(e.clone()));
        }
        bar.set_message(id.to_string());
        let t = std::time::Instant::now();
        let res = ds.load_pair(&specs[pos].id).and_then(|pair| {
            crate::pipeline::Registration::new(&params)
                .cache(cache.as_ref())
                .memo(&memo)
                .generate(!batched)
                .run(&pair)
        });
        bar.inc(1);
        let r = res?;
        Ok(PairRecord {
            id: id.to_string(),
            status: DONE.into(),
            error: None,
            time_s: t.elapsed().as_secs_f64(),
            stages: r
                .timings
                .iter()
                .map(|t| StageTime {
                    stage: t.stage.clone(),
                    ms: t.ms,
                    status: t.status.clone(),
                })
                .collect(),
            result: json!({
                "backend": r.image.as_ref().map(|i| i.provenance.backend.clone()),
                "rre_deg": r.metrics.as_ref().map(|m| m.rre_deg),
                "rte_m": r.metrics.as_ref().map(|m| m.rte_m),
            }),
        })
    };
    let written = run_pending(
        &mut progress,
        &generate_json,
        &mut run_pair,
        &|_, why| json!({ "error": why }),
        &mut |l| log_line(&bar, l),
    );
    bar.finish_and_clear();
    let file = progress.run_file();
    super::bench::print_stage_table(&file.records);
    let computed: usize = stage_totals(&file.records)
        .iter()
        .filter(|s| s.0 == "generation")
        .map(|s| s.2)
        .sum();
    eprintln!(
        "shard {shard}: {} pairs, {computed} generations computed, the others cached (cache: {})",
        file.records.len(),
        cache
            .as_ref()
            .map(|c| c.root().display().to_string())
            .unwrap_or_default()
    );
    written
}

/// One backend run for every missing generation of `ids`; stores what comes back and returns
/// the pairs whose generation failed, with why (their per-pair pass then records the error
/// instead of running the generator alone).
fn generate_batch(
    ds: &Dataset,
    ids: &[String],
    ib: &crate::pipeline::ImageBranchParams,
    cache: &crate::cache::Cache,
) -> std::collections::HashMap<String, String> {
    use crate::pipeline::image_branch::{pending_generation, store_pending};
    let mut errors = std::collections::HashMap::new();
    let memo = crate::pipeline::Memo::default();
    let mut pending = Vec::new();
    for id in ids {
        match ds
            .load_pair(id)
            .and_then(|pair| pending_generation(&pair, ib, cache, &memo))
        {
            Ok(Some(p)) => pending.push(p),
            Ok(None) => {}
            Err(e) => {
                errors.insert(id.clone(), format!("before generation: {e}"));
            }
        }
    }
    let Some(first) = pending.first() else {
        eprintln!("generate: every selected generation is cached already");
        return errors;
    };
    eprintln!(
        "generate: {} generations missing, one batch for {} ({} cached or failed before)",
        pending.len(),
        first.backend.id(),
        ids.len() - pending.len()
    );
    let t = std::time::Instant::now();
    let reqs: Vec<_> = pending.iter().map(|p| p.request.clone()).collect();
    let results = first.backend.generate_batch(&reqs);
    eprintln!(
        "generate: batch of {} finished in {:.1} s",
        reqs.len(),
        t.elapsed().as_secs_f64()
    );
    for (p, r) in pending.iter().zip(results) {
        let stored = r.and_then(|g| store_pending(cache, p, g));
        if let Err(e) = stored {
            eprintln!("generate: {}: {e}", p.pair_id);
            errors.insert(p.pair_id.clone(), format!("generation failed: {e}"));
        }
    }
    errors
}
