//! `cgenreg study k|prompt`: RRE/RTE against K (the paper's figure 6) or per prompt category
//! (figure 4) over the pairs of a manifest, with the same image-branch options as `bench`.

use super::args::{ImageArgs, PipelineArgs};
use super::bench::{log_line, progress_bar, PairsArgs, RunArgs};
use crate::cli::args::ManifestSettings;
use crate::error::{Error, Result};
use crate::pipeline::shard::{run_pending, PairRecord, Progress, RunFile, RunIdentity, DONE};
use crate::pipeline::study::{
    k_settings, markdown_table, parse_ks, plan_study, prompt_settings, study_pair, StudySetting,
};
use crate::report::study_file::{settings_json, study_json, study_report};
use clap::{Args, Subcommand};
use serde_json::{json, Value};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct StudyArgs {
    #[command(subcommand)]
    pub study: StudyCommand,
}

#[derive(Subcommand, Debug)]
pub enum StudyCommand {
    /// RRE/RTE against the number of views K (figure 6); one generation per pair is re-used.
    K(KArgs),
    /// RRE/RTE per prompt category (figure 4): scene-specific, general, minimal,
    /// semantically wrong (+ --custom-scene). Needs one generation per prompt.
    Prompt(PromptArgs),
}

#[derive(Args, Debug)]
pub struct KArgs {
    #[command(flatten)]
    pub common: CommonArgs,
    /// K values (views per side), comma separated; invalid ones are reported as skipped.
    #[arg(long, default_value = "1,2,4,8")]
    pub ks: String,
}

#[derive(Args, Debug)]
pub struct PromptArgs {
    #[command(flatten)]
    pub common: CommonArgs,
    /// A fifth, custom scene description (the shared prefix is kept).
    #[arg(long)]
    pub custom_scene: Option<String>,
}

#[derive(Args, Debug)]
pub struct CommonArgs {
    #[command(flatten)]
    pub pairs: PairsArgs,
    /// Run the generator when a generation is not cached. Default: on for the oracle, the
    /// built-in generator and a cached Cosmos folder (they only read or shade frames), off for
    /// --wfm cosmos (pairs without a cached generation are then skipped and counted).
    #[arg(long)]
    pub generate: bool,
    /// Write the full report (rows, per-pair results, skipped pairs with reasons) as JSON,
    /// rewritten after every pair (resumable, see `bench --shard`).
    #[arg(long)]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

pub fn run(a: StudyArgs) -> Result<()> {
    match a.study {
        StudyCommand::K(k) => {
            let ks = parse_ks(&k.ks)?;
            run_common(&k.common, k_settings(&ks), "study k")
        }
        StudyCommand::Prompt(p) => {
            // The prompt study varies the scene description only: the prefix stays as given.
            let prefix = crate::wfm::prompt::DEFAULT_PREFIX;
            // the scene-specific category describes the data set's own scene when it names one
            let scene =
                crate::dataset::manifest::Dataset::load(&p.common.pairs.manifest)?.scene_prompt;
            let settings = prompt_settings(prefix, scene.as_deref(), p.custom_scene.as_deref());
            run_common(&p.common, settings, "study prompt")
        }
    }
}

/// The study table of a run file, and its skipped / failed pairs.
pub fn print_study(f: &RunFile) -> Result<()> {
    let rep = study_report(f)?;
    outln!("{}", markdown_table(&rep));
    for r in &rep.rows {
        for s in &r.skipped {
            eprintln!("{} · {}: skipped: {}", r.setting, s.pair_id, s.reason);
        }
        for s in &r.failed {
            eprintln!("{} · {}: failed: {}", r.setting, s.pair_id, s.reason);
        }
    }
    Ok(())
}

fn run_common(a: &CommonArgs, settings: Vec<StudySetting>, command: &str) -> Result<()> {
    if a.image.wfm.is_none() {
        return Err(Error::Usage(
            "a study needs the image branch: pass --wfm oracle, builtin, cached or cosmos".into(),
        ));
    }
    a.run.check_output(a.json.as_deref())?;
    let ds = a.pairs.dataset(&a.image)?;
    let specs = a.pairs.select(&ds)?;
    let (params, cache) = a
        .image
        .params_and_cache_for(&a.pipeline, &ManifestSettings::of(&ds))?;
    let generate = a.generate || params.generates_missing();
    let plan = plan_study(&params, &settings)?;
    let shard = a.run.shard();
    let identity = RunIdentity::new(
        command,
        &a.pairs.manifest,
        a.pairs.split.as_deref(),
        a.pairs.limit,
        json!({
            "register": serde_json::to_value(&params)
                .map_err(|e| Error::Encode(format!("serialising parameters: {e}")))?,
            "settings": settings_json(&settings),
            "generate": generate,
        }),
        shard.count,
        specs.iter().map(|s| s.id.clone()).collect(),
    )?;
    let (mut progress, message) =
        Progress::start(identity, shard, a.json.as_deref(), a.run.mode())?;
    if let Some(m) = message {
        eprintln!("{m}");
    }
    let runnable = plan
        .rows
        .iter()
        .filter(|r| r.setting_skipped.is_none())
        .count();
    let bar = progress_bar(progress.positions.len() * runnable);
    let t = std::time::Instant::now();
    // one memo for the run: the VFM model loads once, each file is hashed once
    let memo = crate::pipeline::Memo::default();
    let mut run_pair = |_pos: usize, id: &str| -> Result<PairRecord> {
        let t = std::time::Instant::now();
        let pair = ds.load_pair(id).map_err(|e| e.to_string());
        let outcomes = study_pair(
            &plan,
            pair.as_ref(),
            &params,
            (cache.as_ref(), &memo),
            generate,
            &mut |s| {
                bar.inc(1);
                bar.set_message(format!("{id} · {s}"));
            },
        );
        Ok(PairRecord {
            id: id.to_string(),
            status: DONE.into(),
            error: None,
            time_s: t.elapsed().as_secs_f64(),
            stages: Vec::new(),
            result: json!({ "outcomes": outcomes }),
        })
    };
    let written = run_pending(
        &mut progress,
        &study_json,
        &mut run_pair,
        &|_, _| Value::Null,
        &mut |l| log_line(&bar, l),
    );
    bar.finish_and_clear();
    print_study(&progress.run_file())?;
    eprintln!(
        "{} settings x {} pairs in {:.1} s (shard {shard}; cache: {})",
        settings.len(),
        progress.positions.len(),
        t.elapsed().as_secs_f64(),
        cache
            .as_ref()
            .map(|c| c.root().display().to_string())
            .unwrap_or_else(|| "off".into())
    );
    written?;
    if let Some(path) = &a.json {
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
