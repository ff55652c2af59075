//! `cgenreg study k|prompt`: RRE/RTE against K (the paper's figure 6) or per prompt category
//! (figure 4) over the pairs of a manifest, with the same image-branch options as `bench`.

use super::args::{ImageArgs, PipelineArgs};
use crate::dataset::manifest::Dataset;
use crate::error::{Error, Result};
use crate::pipeline::params::WfmSpec;
use crate::pipeline::study::{
    k_settings, markdown_table, parse_ks, prompt_settings, run_study, StudySetting,
};
use clap::{Args, Subcommand};
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
    /// Dataset manifest (TOML).
    pub manifest: PathBuf,
    /// Only pairs of this split (e.g. 3DMatch, 3DLoMatch).
    #[arg(long)]
    pub split: Option<String>,
    /// Only the first N pairs.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Run the generator when a generation is not cached. Default: on for the oracle, the
    /// built-in generator and a cached Cosmos folder (they only read or shade frames), off for
    /// --wfm cosmos (pairs without a cached generation are then skipped and counted).
    #[arg(long)]
    pub generate: bool,
    /// Write the full report (rows, per-pair results, skipped pairs with reasons) as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

pub fn run(a: StudyArgs) -> Result<()> {
    match a.study {
        StudyCommand::K(k) => {
            let ks = parse_ks(&k.ks)?;
            run_common(&k.common, k_settings(&ks))
        }
        StudyCommand::Prompt(p) => {
            // The prompt study varies the scene description only: the prefix stays as given.
            let prefix = crate::wfm::prompt::DEFAULT_PREFIX;
            let settings = prompt_settings(prefix, p.custom_scene.as_deref());
            run_common(&p.common, settings)
        }
    }
}

fn run_common(a: &CommonArgs, settings: Vec<StudySetting>) -> Result<()> {
    if a.image.wfm.is_none() {
        return Err(Error::Invalid(
            "a study needs the image branch: pass --wfm oracle, builtin, cached or cosmos".into(),
        ));
    }
    let ds = Dataset::load(&a.manifest)?.with_fragment_cache(a.image.fragment_cache_dir());
    let ids: Vec<String> = ds
        .select_pairs(a.split.as_deref(), a.limit)
        .into_iter()
        .map(|p| p.id.clone())
        .collect();
    if ids.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no pairs selected",
            a.manifest.display()
        )));
    }
    let (params, cache) = a.image.params_and_cache(&a.pipeline)?;
    let generate = a.generate
        || !matches!(
            params.image.as_ref().map(|i| &i.backend),
            Some(WfmSpec::Cosmos { .. })
        );
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed}<{eta}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let t = std::time::Instant::now();
    let rep = run_study(
        &ds,
        &ids,
        &params,
        &settings,
        cache.as_ref(),
        generate,
        &mut |p| {
            bar.set_length(p.total as u64);
            bar.set_position(p.done as u64);
            bar.set_message(format!("{} · {}", p.pair, p.setting));
        },
    )?;
    bar.finish_and_clear();
    println!("{}", markdown_table(&rep));
    for r in &rep.rows {
        for s in &r.skipped {
            eprintln!("{} · {}: skipped: {}", r.setting, s.pair_id, s.reason);
        }
        for s in &r.failed {
            eprintln!("{} · {}: failed: {}", r.setting, s.pair_id, s.reason);
        }
    }
    eprintln!(
        "{} settings x {} pairs in {:.1} s (cache: {})",
        settings.len(),
        ids.len(),
        t.elapsed().as_secs_f64(),
        cache
            .as_ref()
            .map(|c| c.root().display().to_string())
            .unwrap_or_else(|| "off".into())
    );
    if let Some(path) = &a.json {
        let s = serde_json::to_string_pretty(&rep)
            .map_err(|e| Error::Invalid(format!("serialising the study: {e}")))?;
        crate::error::write_atomic(path, s.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
