//! `cgenreg cache`: list, verify and remove entries of the content-addressed stage cache.
//! The commands that delete (`rm`, `verify --remove-bad`) only act on a directory that carries
//! the cache's marker file (written when a cache is created; `cache init` marks an existing
//! one) and only ever remove entry folders (`<stage>/<64 hex digits>`), nothing else.

use crate::cache::Cache;
use crate::error::{Error, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct CacheArgs {
    /// Cache directory (default: $CGENREG_CACHE or ~/.cache/cgenreg).
    #[arg(long, global = true)]
    pub dir: Option<PathBuf>,
    #[command(subcommand)]
    pub action: CacheAction,
}

#[derive(Subcommand, Debug)]
pub enum CacheAction {
    /// One line per entry: stage, hash, size, creation time and provenance.
    List {
        /// Only entries of this stage (e.g. generation, vfm-view, lift).
        #[arg(long)]
        stage: Option<String>,
    },
    /// Re-hash every entry against its manifest; exits with an error if any is corrupt.
    Verify {
        /// Remove the corrupt or partial entries found.
        #[arg(long)]
        remove_bad: bool,
    },
    /// Mark an existing directory as a cgenreg cache (a cache made before the marker file
    /// existed), so that `rm` and `verify --remove-bad` may delete its entries.
    Init,
    /// Remove entries: `STAGE/HASHPREFIX` (as `list` prints), or a whole `STAGE`, or --all.
    Rm {
        targets: Vec<String>,
        #[arg(long, conflicts_with = "targets")]
        all: bool,
    },
}

/// The cache as it is: the commands create nothing (except `init`).
fn open(a: &CacheArgs) -> Cache {
    let dir = a
        .dir
        .clone()
        .unwrap_or_else(crate::cache::default_cache_dir);
    Cache::at(dir)
}

fn human_bytes(b: u64) -> String {
    match b {
        b if b >= 1 << 30 => format!("{:.1} GiB", b as f64 / (1u64 << 30) as f64),
        b if b >= 1 << 20 => format!("{:.1} MiB", b as f64 / (1u64 << 20) as f64),
        b if b >= 1 << 10 => format!("{:.1} KiB", b as f64 / 1024.0),
        b => format!("{b} B"),
    }
}

fn provenance_summary(v: &serde_json::Value) -> String {
    let field = |k: &str| v.get(k).and_then(|x| x.as_str()).map(str::to_string);
    let mut parts = Vec::new();
    if let Some(b) = field("backend") {
        parts.push(format!("backend {b}"));
    }
    if let Some(p) = field("prompt") {
        let short: String = p
            .chars()
            .rev()
            .take(40)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        parts.push(format!("prompt …{short}"));
    }
    if let Some(n) = v.get("frame_count").and_then(|x| x.as_u64()) {
        parts.push(format!("{n} frames"));
    }
    if let Some(m) = field("vfm") {
        parts.push(m);
    }
    if parts.is_empty() {
        parts.push(v.to_string().chars().take(60).collect());
    }
    parts.join(", ")
}

pub fn run(a: CacheArgs) -> Result<()> {
    let cache = open(&a);
    match &a.action {
        CacheAction::Init => {
            let n = cache.list()?.len();
            if cache.init()? {
                outln!(
                    "marked {} as a cgenreg cache ({n} entries)",
                    cache.root().display()
                );
            } else {
                outln!(
                    "{} is a cgenreg cache already ({n} entries)",
                    cache.root().display()
                );
            }
            Ok(())
        }
        CacheAction::List { stage } => {
            let entries = cache.list()?;
            let mut total = 0u64;
            let mut n = 0usize;
            outln!("cache {}", cache.root().display());
            for e in entries
                .iter()
                .filter(|e| stage.as_ref().is_none_or(|s| &e.stage == s))
            {
                n += 1;
                total += e.total_bytes;
                let id = format!("{}/{}", e.stage, &e.hash[..12.min(e.hash.len())]);
                match (&e.manifest, &e.problem) {
                    (Some(m), None) => outln!(
                        "{id:<28} {:>10}  created {}  {}",
                        human_bytes(e.total_bytes),
                        m.created_unix,
                        provenance_summary(&m.provenance)
                    ),
                    (_, Some(p)) => outln!("{id:<28} PROBLEM: {p}"),
                    (None, None) => outln!("{id:<28} (no manifest)"),
                }
            }
            outln!("{n} entries, {}", human_bytes(total));
            Ok(())
        }
        CacheAction::Verify { remove_bad } => {
            if *remove_bad && !cache.is_marked() {
                return Err(Error::NotACache {
                    dir: cache.root().to_path_buf(),
                    marker: crate::cache::MARKER.into(),
                });
            }
            let reports = cache.verify_all()?;
            let mut bad = 0usize;
            let mut kept = 0usize;
            for r in &reports {
                if let Err(e) = &r.result {
                    bad += 1;
                    outln!(
                        "CORRUPT {}/{}: {e}",
                        r.stage,
                        &r.hash[..12.min(r.hash.len())]
                    );
                    if *remove_bad {
                        match cache.remove_entry(&r.stage, &r.hash) {
                            Ok(_) => outln!("  removed"),
                            Err(e @ Error::NotACache { .. }) => return Err(e),
                            Err(e) => {
                                kept += 1;
                                outln!("  not removed: {e}");
                            }
                        }
                    }
                }
            }
            outln!(
                "{} entries verified, {bad} corrupt or partial",
                reports.len()
            );
            if kept > 0 {
                return Err(Error::Cache(format!(
                    "{kept} corrupt or partial entries in {} were not removed (see above)",
                    cache.root().display()
                )));
            }
            if bad > 0 && !remove_bad {
                return Err(Error::Cache(format!(
                    "{bad} corrupt or partial cache entries in {} (they are never used; \
                     `cgenreg cache verify --remove-bad` removes them)",
                    cache.root().display()
                )));
            }
            Ok(())
        }
        CacheAction::Rm { targets, all } => {
            if *all {
                outln!("removed {} entries", cache.remove_all()?);
                return Ok(());
            }
            if targets.is_empty() {
                return Err(Error::Usage(
                    "cgenreg cache rm: give STAGE/HASHPREFIX, STAGE, or --all".into(),
                ));
            }
            for t in targets {
                match t.split_once('/') {
                    Some((stage, hash)) => {
                        if cache.remove_entry(stage, hash)? {
                            outln!("removed {t}");
                        } else {
                            return Err(Error::Missing(format!("no cache entry {t}")));
                        }
                    }
                    None => {
                        // A typo in a stage name is an error, not "removed 0 entries".
                        if !cache.root().join(t).is_dir() {
                            let mut stages: Vec<String> =
                                cache.list()?.into_iter().map(|e| e.stage).collect();
                            stages.dedup();
                            return Err(Error::Missing(format!(
                                "cgenreg cache rm {t:?}: no stage of that name in {} (stages \
                                 there: {})",
                                cache.root().display(),
                                if stages.is_empty() {
                                    "none".to_string()
                                } else {
                                    stages.join(", ")
                                }
                            )));
                        }
                        outln!("removed {} entries of stage {t}", cache.remove_stage(t)?)
                    }
                }
            }
            Ok(())
        }
    }
}
