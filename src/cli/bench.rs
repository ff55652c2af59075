use super::args::{ImageArgs, PipelineArgs};
use crate::dataset::fragment_cache::pair_summary;
use crate::dataset::manifest::Dataset;
use crate::error::{Error, Result};
use crate::metrics::{PairMetrics, Summary};
use crate::pipeline::register_pair_cached;
use clap::Args;
use serde::Serialize;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Dataset manifest (TOML).
    pub manifest: PathBuf,
    /// Only pairs of this split (e.g. 3DMatch, 3DLoMatch); default all, reported per split.
    #[arg(long)]
    pub split: Option<String>,
    /// Only the first N pairs.
    #[arg(long)]
    pub limit: Option<usize>,
    /// List the pairs and exit.
    #[arg(long)]
    pub list: bool,
    /// Write per-pair results and a summary as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

#[derive(Serialize)]
struct PairRow {
    id: String,
    split: String,
    source: String,
    target: String,
    rre_deg: Option<f64>,
    rte_m: Option<f64>,
    inlier_ratio: Option<f64>,
    success: Option<bool>,
    time_s: f64,
    error: Option<String>,
}

#[derive(Serialize)]
struct BenchJson<'a> {
    manifest: String,
    params: &'a crate::pipeline::RegisterParams,
    pairs: Vec<PairRow>,
    summary: Vec<SplitSummary>,
}

#[derive(Serialize)]
struct SplitSummary {
    split: String,
    recall: f64,
    #[serde(flatten)]
    summary: Summary,
    time_per_pair_s: f64,
}

pub fn run(a: BenchArgs) -> Result<()> {
    let ds = Dataset::load(&a.manifest)?.with_fragment_cache(a.image.fragment_cache_dir());
    let specs = ds.select_pairs(a.split.as_deref(), a.limit);
    if a.list {
        for p in &specs {
            println!("{}\t{}", p.id, p.split);
        }
        return Ok(());
    }
    if specs.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no pairs selected",
            a.manifest.display()
        )));
    }
    let (params, cache) = a.image.params_and_cache(&a.pipeline)?;
    let (mut n_cached, mut n_computed) = (0usize, 0usize);
    let mut stage_ms: Vec<(String, f64, usize, usize)> = Vec::new();
    let mut warnings = 0usize;
    let bar = indicatif::ProgressBar::new(specs.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed}<{eta}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut rows = Vec::new();
    for spec in &specs {
        bar.set_message(spec.id.clone());
        let t = std::time::Instant::now();
        let res = ds.load_pair_status(&spec.id).and_then(|(pair, st)| {
            let load_ms = t.elapsed().as_secs_f64() * 1e3;
            let (hit, rebuilt) = pair_summary(&st);
            for why in rebuilt {
                bar.println(format!(
                    "{}: warning: fragment cache: {why} (rebuilt)",
                    spec.id
                ));
                warnings += 1;
            }
            let loaded = hit == Some(true);
            let mut r = register_pair_cached(&pair, &params, cache.as_ref())?;
            r.timings.insert(
                0,
                crate::pipeline::StageTiming {
                    stage: "load pair".into(),
                    ms: load_ms,
                    status: if loaded { "cached" } else { "computed" }.into(),
                },
            );
            Ok(r)
        });
        let time_s = t.elapsed().as_secs_f64();
        let row = match res {
            Ok(r) => {
                for t in &r.timings {
                    let hit = crate::pipeline::image_branch::is_cached(&t.status);
                    if hit {
                        n_cached += 1;
                    } else {
                        n_computed += 1;
                    }
                    match stage_ms.iter_mut().find(|s| s.0 == t.stage) {
                        Some(s) => {
                            s.1 += t.ms;
                            s.2 += hit as usize;
                            s.3 += !hit as usize;
                        }
                        None => stage_ms.push((t.stage.clone(), t.ms, hit as usize, !hit as usize)),
                    }
                }
                for w in &r.warnings {
                    if w.contains("corrupt") || w.contains("could not write cache") {
                        bar.println(format!("{}: warning: {w}", spec.id));
                        warnings += 1;
                    }
                }
                PairRow {
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
                }
            }
            Err(e) => {
                bar.println(format!("{}: error: {e}", spec.id));
                PairRow {
                    id: spec.id.clone(),
                    split: spec.split.clone(),
                    source: String::new(),
                    target: String::new(),
                    rre_deg: None,
                    rte_m: None,
                    inlier_ratio: None,
                    success: Some(false),
                    time_s,
                    error: Some(e.to_string()),
                }
            }
        };
        rows.push(row);
        bar.inc(1);
    }
    bar.finish_and_clear();

    let mut splits: Vec<String> = rows.iter().map(|r| r.split.clone()).collect();
    splits.dedup();
    splits.sort();
    splits.dedup();
    let mut summaries = Vec::new();
    println!(
        "| split | pairs | RR % | RA@5° | RA@10° | RA@45° | RRE mean° | RRE med° | TA@5cm | TA@10cm | TA@25cm | RTE mean cm | RTE med cm | s/pair |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for split in &splits {
        let sel: Vec<&PairRow> = rows.iter().filter(|r| &r.split == split).collect();
        // A failed run counts as a failure with infinite error, so recall stays honest.
        let pm: Vec<PairMetrics> = sel
            .iter()
            .map(|r| PairMetrics {
                rre_deg: r.rre_deg.unwrap_or(f64::INFINITY),
                rte_m: r.rte_m.unwrap_or(f64::INFINITY),
                inlier_ratio: r.inlier_ratio.unwrap_or(0.0),
                success: r.success.unwrap_or(false),
            })
            .collect();
        let s = Summary::from_pairs(&pm);
        let tpp = sel.iter().map(|r| r.time_s).sum::<f64>() / sel.len().max(1) as f64;
        println!(
            "| {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.2} | {:.2} | {:.1} | {:.1} | {:.1} | {:.2} | {:.2} | {:.3} |",
            split,
            s.n,
            100.0 * s.recall,
            100.0 * s.rot_acc_5,
            100.0 * s.rot_acc_10,
            100.0 * s.rot_acc_45,
            s.rre_mean,
            s.rre_median,
            100.0 * s.trans_acc_5cm,
            100.0 * s.trans_acc_10cm,
            100.0 * s.trans_acc_25cm,
            100.0 * s.rte_mean,
            100.0 * s.rte_median,
            tpp
        );
        summaries.push(SplitSummary {
            split: split.clone(),
            recall: s.recall,
            summary: s,
            time_per_pair_s: tpp,
        });
    }
    {
        println!();
        println!("| stage | total s | cached | computed |");
        println!("|---|---|---|---|");
        for (name, ms, c, n) in &stage_ms {
            println!("| {name} | {:.2} | {c} | {n} |", ms / 1e3);
        }
        println!(
            "cache ({}): {n_cached} stage results were cache hits, {n_computed} were computed{}",
            cache
                .as_ref()
                .map(|c| c.root().display().to_string())
                .or_else(|| ds
                    .fragment_cache
                    .as_ref()
                    .map(|d| format!("fragments only: {}", d.display())))
                .unwrap_or_else(|| "off".into()),
            if warnings > 0 {
                format!("; {warnings} cache problems reported above")
            } else {
                String::new()
            }
        );
    }
    if let Some(path) = &a.json {
        let out = BenchJson {
            manifest: a.manifest.display().to_string(),
            params: &params,
            pairs: rows,
            summary: summaries,
        };
        let s = serde_json::to_string_pretty(&out)
            .map_err(|e| Error::Invalid(format!("serialising results: {e}")))?;
        crate::error::write_atomic(path, s.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
