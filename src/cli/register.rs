use super::args::{ImageArgs, PipelineArgs};
use crate::cli::args::ManifestSettings;
use crate::dataset::fragment_cache::pair_summary;
use crate::dataset::manifest::Dataset;
use crate::dataset::ScanPair;
use crate::error::{Error, Result};
use crate::metrics::SuccessCriterion;
use crate::pipeline::{Registration, RegistrationResult};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct RegisterArgs {
    /// Source cloud file (.ply .pcd .npy .pth .bin .xyz).
    #[arg(long, requires = "target", conflicts_with = "manifest")]
    pub source: Option<PathBuf>,
    /// Target cloud file.
    #[arg(long, requires = "source")]
    pub target: Option<PathBuf>,
    /// Ground truth target_from_source (4x4 text or .npy) for --source/--target.
    #[arg(long, requires = "source")]
    pub gt: Option<PathBuf>,
    /// Dataset manifest (TOML).
    #[arg(long, requires = "pair")]
    pub manifest: Option<PathBuf>,
    /// Pair id within the manifest (see `cgenreg bench --list`).
    #[arg(long, requires = "manifest")]
    pub pair: Option<String>,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
    /// Write the selected correspondences (indices, coordinates, scores, posteriors, branch,
    /// inlier flags under the estimate and the ground truth) to this .npz file.
    #[arg(long, value_name = "FILE.npz")]
    pub export_corr: Option<PathBuf>,
    /// Replace an existing --export-corr file even when it is not an .npz archive.
    #[arg(long, requires = "export_corr")]
    pub force: bool,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    #[command(flatten)]
    pub image: ImageArgs,
}

/// Where the pair of a registration comes from.
pub enum PairInput {
    /// Two cloud files and an optional ground-truth file (`--source --target [--gt]`).
    Files {
        source: PathBuf,
        target: PathBuf,
        gt: Option<PathBuf>,
    },
    /// A pair of a dataset manifest (`--manifest --pair`).
    Manifest { manifest: PathBuf, pair: String },
    /// A pair already in memory, and how long making it took (ms).
    Loaded { pair: Box<ScanPair>, load_ms: f64 },
}

/// What one registration produced: the pair, the settings it ran with, the result and the
/// fusion inputs (for the correspondence export).
pub struct Registered {
    pub pair: ScanPair,
    pub params: crate::pipeline::RegisterParams,
    pub result: RegistrationResult,
    pub inputs: crate::pipeline::tail::FusionInputs,
}

/// A loaded pair, whether its fragments came from the cache, the load time (ms), and what its
/// data set names for it (preset, scene description, geometric features).
type LoadedPair = (ScanPair, Option<bool>, f64, ManifestSettings);

/// The pair, whether its clouds came from the fragment cache (None: no cache involved), the
/// time it took (ms), and what its manifest names for it.
fn load_pair(input: PairInput, image: &ImageArgs) -> Result<LoadedPair> {
    let t0 = std::time::Instant::now();
    let ms = |t: std::time::Instant| t.elapsed().as_secs_f64() * 1e3;
    match input {
        PairInput::Files { source, target, gt } => {
            crate::dataset::pair_from_files(&source, &target, gt.as_deref())
                .map(|p| (p, None, ms(t0), ManifestSettings::default()))
        }
        PairInput::Manifest { manifest, pair } => {
            let ds = Dataset::load(&manifest)?.with_fragment_cache(image.fragment_cache()?);
            let (p, st) = ds.load_pair_status(&pair)?;
            let (hit, rebuilt) = pair_summary(&st);
            for why in rebuilt {
                eprintln!("warning: fragment cache: {why}");
            }
            Ok((p, hit, ms(t0), ManifestSettings::of_pair(&ds, &pair)))
        }
        PairInput::Loaded { pair, load_ms } => {
            Ok((*pair, None, load_ms, ManifestSettings::default()))
        }
    }
}

/// What `cgenreg register` computes for `input` under its pipeline and image options.
fn register_input(
    input: PairInput,
    pipeline: &PipelineArgs,
    image: &ImageArgs,
) -> Result<Registered> {
    let (pair, load_hit, load_ms, settings) = load_pair(input, image)?;
    let (params, cache) = image.params_and_cache_for(pipeline, &settings)?;
    let memo = crate::pipeline::Memo::default();
    let mut res = Registration::new(&params)
        .cache(cache.as_ref())
        .memo(&memo)
        .keep(true)
        .run(&pair)?;
    let inputs = res
        .inputs
        .take()
        .map(std::sync::Arc::unwrap_or_clone)
        .ok_or_else(|| crate::Error::Missing("the registration kept no fusion inputs".into()))?;
    res.timings.insert(
        0,
        crate::pipeline::StageTiming {
            name: None,
            stage: "load pair".into(),
            ms: load_ms,
            status: match load_hit {
                Some(true) => "cached".into(),
                _ => "computed".into(),
            },
        },
    );
    res.total_ms += load_ms;
    Ok(Registered {
        pair,
        params,
        result: res,
        inputs,
    })
}

/// `cgenreg register` without its printing: `input` registered under `options`, the command's
/// own pipeline and image-branch options (e.g. `["--voxel", "0.1"]`), with the same defaults,
/// checks and errors. The Python package's `register` and `register_pair`.
pub fn register_with_options(input: PairInput, options: &[String]) -> Result<Registered> {
    let a = super::parse_settings(options)?;
    register_input(input, &a.pipeline, &a.image)
}

pub fn run(a: RegisterArgs) -> Result<()> {
    if let Some(path) = &a.export_corr {
        // before the work: a bad output path fails at once
        crate::io::output::prepare(path, crate::io::output::OutputKind::Npz, a.force)?;
    }
    let input = match (a.source, a.target, a.manifest, a.pair) {
        (Some(source), Some(target), _, _) => PairInput::Files {
            source,
            target,
            gt: a.gt,
        },
        (_, _, Some(manifest), Some(pair)) => PairInput::Manifest { manifest, pair },
        _ => {
            return Err(Error::Usage(
                "give --source and --target, or --manifest and --pair".into(),
            ))
        }
    };
    let Registered {
        pair,
        params,
        result: res,
        inputs,
    } = register_input(input, &a.pipeline, &a.image)?;
    if let Some(path) = &a.export_corr {
        let t = crate::pipeline::export::export_correspondences(
            path, a.force, &pair, &params, &inputs, None, &res,
        )?;
        // stderr: stdout stays the result (JSON with --json)
        eprintln!("wrote {} correspondences to {}", t.len(), path.display());
    }
    if a.json {
        let s = serde_json::to_string_pretty(&res)
            .map_err(|e| Error::Encode(format!("serialising the result: {e}")))?;
        outln!("{s}");
    } else {
        print_human(&res);
    }
    Ok(())
}

pub fn print_human(r: &RegistrationResult) {
    outln!(
        "pair {}: source {} -> target {}",
        r.pair_id,
        r.source_name,
        r.target_name
    );
    outln!(
        "geometric features: {}; image branch: {}",
        r.geo_features,
        r.image_branch.as_deref().unwrap_or("off")
    );
    if let Some(f) = r.fusion_provenance() {
        outln!("{f}");
    }
    if let Some(s) = &r.scales {
        outln!("{}", s.provenance());
    }
    outln!(
        "keypoints: {} source, {} target; {} correspondences, {} inliers ({})",
        r.n_source_keypoints,
        r.n_target_keypoints,
        r.n_correspondences,
        r.n_inliers,
        r.estimator
    );
    outln!("estimated target_from_source (p_target = T * p_source):");
    for row in &r.target_from_source {
        outln!(
            "  {:>12.8} {:>12.8} {:>12.8} {:>12.8}",
            row[0],
            row[1],
            row[2],
            row[3]
        );
    }
    match &r.metrics {
        Some(m) => outln!(
            "vs ground truth: RRE {:.3} deg, RTE {:.3} m, inlier ratio {:.1} %, {}",
            m.rre_deg,
            m.rte_m,
            100.0 * m.inlier_ratio,
            judged(m.success, &m.criterion)
        ),
        None => outln!("no ground truth: metrics not computed"),
    }
    if let Some(also) = r.metrics.as_ref().and_then(|m| m.also) {
        println!("  also: {}", judged(also.success, &also.criterion));
    }
    if let Some(c) = &r.convention {
        match &c.warning {
            Some(w) => outln!("WARNING: {w}"),
            None => outln!(
                "ground truth convention: consistent ({:.0} % of source keypoints within {:.0} cm \
                 under the GT, {:.0} % under its inverse)",
                100.0 * c.overlap_gt,
                100.0 * c.threshold_m,
                100.0 * c.overlap_inverse
            ),
        }
    }
    if let Some(img) = &r.image {
        outln!(
            "image branch: frames from {} ({}); VFM {}",
            img.provenance.backend,
            img.provenance.model,
            img.vfm
        );
        let linked =
            |l: &[Option<crate::vfm::lift::PixelLink>]| l.iter().filter(|x| x.is_some()).count();
        outln!(
            "  views: source {:?}, target {:?}; keypoints with a pixel: {}/{} source, {}/{} target",
            img.source_views
                .iter()
                .map(|v| v.generated_index)
                .collect::<Vec<_>>(),
            img.target_views
                .iter()
                .map(|v| v.generated_index)
                .collect::<Vec<_>>(),
            linked(&img.source_links),
            img.source_links.len(),
            linked(&img.target_links),
            img.target_links.len()
        );
    }
    let shown = r.convention.as_ref().and_then(|c| c.warning.as_ref());
    for w in r.warnings.iter().filter(|w| Some(*w) != shown) {
        outln!("warning: {w}");
    }
    outln!("stage timings:");
    for t in &r.timings {
        outln!("  {:<28} {:>9.1} ms  {}", t.stage, t.ms, t.status);
    }
    outln!("  {:<28} {:>9.1} ms", "total", r.total_ms);
}

/// "SUCCESS (RRE ≤ 5°, RTE ≤ 2 m)" or "FAILURE (...)": a verdict with the criterion it used.
fn judged(success: bool, c: &SuccessCriterion) -> String {
    format!(
        "{} ({})",
        if success { "SUCCESS" } else { "FAILURE" },
        c.label()
    )
}
