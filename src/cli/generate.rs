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
use crate::error::{Error, Result};
use crate::pipeline::shard::{
    run_pending, stage_totals, PairRecord, Progress, RunFile, RunIdentity, StageTime, DONE,
};
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
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

/// Generate output bytes for a run file.
pub fn generate_json(f: &RunFile) -> Result<Vec<u8>> {
    let v = json!({
        "manifest": f.run.identity.manifest,
        "params": f.run.identity.params,
        "run": f.run,
        "records": f.records,
    });
    serde_json::to_vec_pretty(&v).map_err(|e| Error::Invalid(format!("serialising: {e}")))
}

pub fn run(a: GenerateArgs) -> Result<()> {
    if a.image.wfm.is_none() {
        return Err(Error::Invalid(
            "generate fills the cache of the image branch: pass --wfm builtin, oracle, cached or \
             cosmos"
                .into(),
        ));
    }
    if a.image.no_cache {
        return Err(Error::Invalid(
            "generate writes into the stage cache: --no-cache makes no sense here".into(),
        ));
    }
    let ds = a.pairs.dataset(&a.image)?;
    let specs = a.pairs.select(&ds)?;
    let (params, cache) = a.image.params_and_cache(&a.pipeline)?;
    let Some(ib) = params.image.clone() else {
        return Err(Error::Invalid("no image branch".into()));
    };
    let shard = a.run.shard();
    let identity = RunIdentity::new(
        "generate",
        &a.pairs.manifest,
        a.pairs.split.as_deref(),
        a.pairs.limit,
        serde_json::to_value(&params)
            .map_err(|e| Error::Invalid(format!("serialising parameters: {e}")))?,
        shard.count,
        specs.iter().map(|s| s.id.clone()).collect(),
    )?;
    let (mut progress, message) =
        Progress::start(identity, shard, a.json.as_deref(), a.run.mode())?;
    if let Some(m) = message {
        eprintln!("{m}");
    }
    let bar = progress_bar(progress.positions.len());
    let mut run_pair = |pos: usize, id: &str| -> Result<PairRecord> {
        bar.set_message(id.to_string());
        let t = std::time::Instant::now();
        let res = ds.load_pair(&specs[pos].id).and_then(|pair| {
            crate::pipeline::image_branch::register_with_image_keep(
                &pair,
                &params,
                &ib,
                cache.as_ref(),
                true,
            )
        });
        bar.inc(1);
        let (r, _) = res?;
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
