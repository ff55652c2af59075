//! `cgenreg inspect` and `cgenreg screenshot`: the inspector on a dataset pair, in a window or
//! rendered headless to a PNG.

use super::args::{ImageArgs, PipelineArgs};
use crate::app::controls::RunSelection;
use crate::app::pairs_panel::PairSort;
use crate::app::worker::PipelineWorker;
use crate::app::{Command, MatchColorMode, Panel};
use crate::error::{Error, Result};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug, Default)]
pub struct InspectArgs {
    /// Dataset manifest to open (default: the bundled synthetic demo, no download).
    #[arg(long)]
    pub manifest: Option<PathBuf>,
    /// Pair id within the manifest (default: its first pair).
    #[arg(long)]
    pub pair: Option<String>,
    /// Open the bundled demo even when other data was opened last time.
    #[arg(long, conflicts_with = "manifest")]
    pub demo: bool,
    /// Two `cgenreg bench --json` outputs to compare in the Compare tab (run A, then run B).
    #[arg(long, num_args = 2, value_names = ["A.json", "B.json"])]
    pub compare: Option<Vec<PathBuf>>,
    #[command(flatten)]
    pub pipeline: Option<PipelineArgs>,
    /// Image branch (WFM backend, prompt, VFM, K, margin) and stage cache; the controls
    /// start from these.
    #[command(flatten)]
    pub image: Option<ImageArgs>,
}

#[derive(Args, Debug)]
pub struct ScreenshotArgs {
    /// Dataset manifest (default: the bundled synthetic demo).
    #[arg(long)]
    pub manifest: Option<PathBuf>,
    /// Pair id within the manifest (default: its first pair).
    #[arg(long)]
    pub pair: Option<String>,
    /// Panel to render: pairs, views, 3d, posterior, plots, stages, compare or hypotheses.
    #[arg(long, default_value = "3d")]
    pub panel: String,
    /// Two `cgenreg bench --json` outputs (run A, then run B) shown in the Compare tab; with
    /// `--panel compare` nothing is registered, and the dataset shown is --manifest, else run
    /// A's manifest when it is found here.
    #[arg(long, num_args = 2, value_names = ["A.json", "B.json"])]
    pub compare: Option<Vec<PathBuf>>,
    /// With --compare: the pair selected in the Compare tab (default: the first row, flipped
    /// pairs first).
    #[arg(long, requires = "compare")]
    pub compare_pair: Option<String>,
    /// Output PNG: a new file in an existing folder, or a PNG to replace.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing --out file even when it is not a PNG.
    #[arg(long)]
    pub force: bool,
    #[arg(long, default_value_t = 1600)]
    pub width: u32,
    #[arg(long, default_value_t = 1000)]
    pub height: u32,
    /// Correspondence colours: gt (green inlier / red outlier under ground truth),
    /// categorical or confidence.
    #[arg(long, value_enum, default_value = "gt")]
    pub match_colors: MatchColorMode,
    /// Number of correspondences drawn (highest fused score first).
    #[arg(long, default_value_t = 150)]
    pub matches: usize,
    /// Pose the source is drawn under in the 3D view: estimated, gt, initial or all.
    #[arg(long, value_enum, default_value_t = Alignment::Estimated)]
    pub alignment: Alignment,
    /// Draw only the correspondences the estimator kept (SC2-PCR inliers).
    #[arg(long)]
    pub only_survivors: bool,
    /// Colour mode of both clouds in the 3D view.
    #[arg(long, value_enum, default_value = "fixed")]
    pub cloud_colors: crate::app::view3d::CloudColorMode,
    /// Show each view's depth frame (as the WFM saw it) instead of the generated view.
    #[arg(long)]
    pub depth_frames: bool,
    /// The views panel's view pair, as SOURCE,TARGET view indices (e.g. 0,1); default: the
    /// pair holding the most shown matches.
    #[arg(long, value_parser = parse_view_pair)]
    pub view_pair: Option<(usize, usize)>,
    /// Depth cue of the 3D view's points: eye-dome lighting, normal shading or none.
    #[arg(long, value_enum, default_value = "edl")]
    pub depth_cue: crate::app::render3d::DepthCue,
    /// Who draws the 3D view's points: auto (CPU splatting under a software GL such as the
    /// headless llvmpipe, GL points on a GPU), gl or cpu.
    #[arg(long, value_enum, default_value = "auto")]
    pub rasterizer: crate::app::render3d::Rasterizer,
    /// Run every pair of the manifest through the worker first, as the pair browser's "Run
    /// all" does (fills the browser and the RRE/RTE plot; a pair that cannot be registered is
    /// an error row), then show --pair.
    #[arg(long, alias = "all-pairs")]
    pub run_all: bool,
    /// The pair browser's order: COLUMN[:asc|:desc], COLUMN one of pair, split, status, rre,
    /// rte, inliers, corr, time (e.g. rre:desc, worst RRE first; the default).
    #[arg(long, value_parser = PairSort::parse)]
    pub sort: Option<PairSort>,
    /// Run the K sweep over the manifest's pairs first (e.g. 1,2,4,8), as the plots panel's
    /// "Run K sweep" button does.
    #[arg(long)]
    pub k_sweep: Option<String>,
    /// Run the prompt study over the manifest's pairs first ("Run prompt study").
    #[arg(long)]
    pub prompt_study: bool,
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Image branch (--wfm oracle|builtin|cached, prompt, VFM, K, margin) and stage cache.
    #[command(flatten)]
    pub image: ImageArgs,
}

fn parse_view_pair(s: &str) -> std::result::Result<(usize, usize), String> {
    let bad = || format!("{s:?}: expected SOURCE,TARGET view indices, e.g. 0,1");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    Ok((
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    ))
}

#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum Alignment {
    Estimated,
    Gt,
    Initial,
    All,
}

/// The bundled synthetic demo's manifest (next to the sources, else under the working dir).
pub fn demo_manifest() -> PathBuf {
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml");
    if built.is_file() {
        built
    } else {
        PathBuf::from("assets/demo/demo.toml")
    }
}

fn open(
    manifest: Option<&Path>,
    pair: Option<&str>,
    pipeline: &PipelineArgs,
    image: &ImageArgs,
) -> Result<(PipelineWorker, String)> {
    let manifest = manifest
        .map(Path::to_path_buf)
        .unwrap_or_else(demo_manifest);
    // fragments rebuilt from raw RGB-D frames are kept in the stage cache, as in `register`
    let dataset = crate::dataset::manifest::Dataset::load(&manifest)?
        .with_fragment_cache(image.fragment_cache()?);
    let mut params = pipeline.to_params(image.wfm.is_some(), dataset.preset);
    params.image = image.to_image_params()?;
    let mut worker = PipelineWorker::new(dataset, params);
    worker.set_cache(image.open_cache()?);
    let ids = worker.pair_ids();
    let id = match pair {
        Some(p) if ids.iter().any(|i| i == p) => p.to_string(),
        Some(p) => {
            return Err(Error::Invalid(format!(
                "{}: no pair {p:?}; pairs: {}",
                manifest.display(),
                ids.join(", ")
            )))
        }
        None => ids.first().cloned().ok_or_else(|| {
            Error::Invalid(format!(
                "{}: the manifest lists no pairs",
                manifest.display()
            ))
        })?,
    };
    Ok((worker, id))
}

fn default_args() -> (PipelineArgs, ImageArgs) {
    use clap::Parser;
    #[derive(Parser)]
    struct P {
        #[command(flatten)]
        p: PipelineArgs,
        #[command(flatten)]
        i: ImageArgs,
    }
    let p = P::parse_from(["cgenreg"]);
    (p.p, p.i)
}

pub fn run_inspect(a: InspectArgs) -> Result<()> {
    let (dp, mut di) = default_args();
    if a.manifest.is_none() {
        // The bundled demo (8 frames per sequence) runs the whole method out of the box: the
        // built-in generator (NOT a WFM) + XFeat, with L = 8, m = 1 and K = 2 views per side.
        di.wfm = Some(crate::pipeline::params::WfmSpec::Builtin);
        di.frames = 8;
        di.margin = 1;
        di.k = 2;
    }
    let explicit = a.pipeline.is_some() || a.image.is_some();
    let pipeline = a.pipeline.unwrap_or(dp);
    let image = a.image.unwrap_or(di);
    let (worker, id) = open(a.manifest.as_deref(), a.pair.as_deref(), &pipeline, &image)?;
    let model = worker.initial_model(Some(&id));
    // Without an explicit dataset, the data opened last time comes back (the demo when that
    // fails); `screenshot` and the tests never read the settings file.
    let initial = if a.manifest.is_none() && !a.demo {
        crate::app::startup_commands(crate::app::default_settings_path().as_deref(), &id)
    } else {
        vec![Command::SelectPair(id)]
    };
    // Options on the command line (or --demo) set the pipeline; otherwise the settings saved
    // last time do, when there are any. Either way the controls show what runs.
    let persisted = crate::app::default_settings_path().is_some_and(|p| p.is_file());
    let worker_settings = (explicit || a.demo || !persisted).then(|| worker.params().clone());
    let compare = a.compare.map(|v| (v[0].clone(), v[1].clone()));
    crate::app::run_gui_configured(model, Box::new(worker), initial, worker_settings, |app| {
        if let Some((x, y)) = compare {
            app.compare_runs(x, y);
        }
    })
    .map_err(Error::Invalid)
}

/// `screenshot --compare A B --panel compare`: the Compare tab over the two runs, without
/// registering anything.
fn run_compare_screenshot(a: &ScreenshotArgs, runs: &[PathBuf], panel: Panel) -> Result<()> {
    let loaded =
        crate::app::compare_panel::load_comparison(&runs[0], &runs[1]).map_err(Error::Invalid)?;
    let manifest = a.manifest.clone().or_else(|| loaded.a.manifest.clone());
    let worker = PipelineWorker::open_manifest(
        &manifest.unwrap_or_else(demo_manifest),
        a.pipeline.to_params(false, None),
    )?;
    let mut model = worker.initial_model(None);
    // nothing runs: no "load + register" stage in progress
    model.stages.clear();
    model.image_branch_note = None;
    let c = &loaded.comparison;
    let rows = {
        let mut st = crate::app::compare_panel::CompareState::default();
        st.set_loaded(loaded.clone());
        st.rows()
    };
    let selected = match &a.compare_pair {
        Some(id) if c.pairs.iter().any(|p| &p.id == id) => Some(id.clone()),
        Some(id) => {
            return Err(Error::Invalid(format!(
                "--compare-pair {id:?}: not a pair of both runs"
            )))
        }
        None => rows.first().map(|&i| c.pairs[i].id.clone()),
    };
    eprint!("{}", crate::metrics::compare::table(c));
    // the controls show what the worker would run (nothing runs for this screenshot)
    let params = worker.params().clone();
    crate::io::output::prepare(&a.out, crate::io::output::OutputKind::Png, a.force)?;
    crate::app::headless::render_screenshot_with(
        &model,
        panel,
        (a.width, a.height),
        &a.out,
        |app| {
            app.params = params;
            app.compare.set_loaded(loaded);
            app.compare.selected = selected;
        },
    )
    .map_err(|e| Error::Invalid(format!("cannot render the screenshot headless: {e}")))?;
    eprintln!("wrote {}", a.out.display());
    Ok(())
}

pub fn run_screenshot(a: ScreenshotArgs) -> Result<()> {
    // before the work, and again right before the write below
    crate::io::output::prepare(&a.out, crate::io::output::OutputKind::Png, a.force)?;
    let panel = Panel::from_name(&a.panel).ok_or_else(|| {
        Error::Invalid(format!(
            "--panel {:?}: expected pairs, views, 3d, posterior, plots, stages, compare or hypotheses",
            a.panel
        ))
    })?;
    match (&a.compare, panel) {
        (Some(runs), Panel::Compare) => return run_compare_screenshot(&a, runs, panel),
        (Some(_), _) => {
            return Err(Error::Invalid(
                "--compare renders the Compare tab: use it with --panel compare".into(),
            ))
        }
        (None, Panel::Compare) => {
            return Err(Error::Invalid(
                "--panel compare needs two runs: --compare A.json B.json".into(),
            ))
        }
        (None, _) => {}
    }
    let (mut worker, id) = open(
        a.manifest.as_deref(),
        a.pair.as_deref(),
        &a.pipeline,
        &a.image,
    )?;
    if a.run_all {
        let t = std::time::Instant::now();
        let s = worker.run_all(RunSelection::All, &mut |p| {
            if let Some(r) = &p.row {
                match &r.status {
                    crate::app::model::PairStatus::Failed(why) => {
                        eprintln!("[{}/{}] {}: error: {why}", p.done, p.total, r.id)
                    }
                    _ => eprintln!(
                        "[{}/{}] {}: {} RRE {:.2}° RTE {:.1} cm, {} corr. ({:.0} ms)",
                        p.done,
                        p.total,
                        r.id,
                        r.outcome().label(),
                        r.rre_deg.unwrap_or(f64::NAN),
                        r.rte_m.unwrap_or(f64::NAN) * 100.0,
                        r.correspondences.unwrap_or(0),
                        r.time_ms.unwrap_or(f64::NAN)
                    ),
                }
            }
        });
        eprintln!(
            "run all: {} pairs in {:.1} s: {} success, {} failure, {} error",
            s.done,
            t.elapsed().as_secs_f64(),
            s.success,
            s.failure,
            s.errors
        );
    }
    let mut studies = Vec::new();
    if let Some(ks) = &a.k_sweep {
        studies.push(crate::app::StudyRequest::K(
            crate::pipeline::study::parse_ks(ks)?,
        ));
    }
    if a.prompt_study {
        studies.push(crate::app::StudyRequest::Prompt);
    }
    for req in studies {
        let t = std::time::Instant::now();
        let rep = worker.run_study(&req, &mut |_, _| {})?;
        eprint!("{}", crate::pipeline::study::markdown_table(&rep));
        eprintln!("({:.1} s)", t.elapsed().as_secs_f64());
    }
    let t = std::time::Instant::now();
    let mut model = worker.run_pair(&id)?;
    eprintln!(
        "registered {id} in {:.0} ms ({} matches)",
        t.elapsed().as_secs_f64() * 1e3,
        model.matches.len()
    );
    // Figure 7 (Noisy-AND against Noisy-OR), as the inspector shows it after a run.
    if let Some(curves) = worker.fusion_pr_curves() {
        model.plots.pr_curves = curves;
        model.plots.figure7_pending = false;
    }
    if panel == Panel::Hypotheses {
        // the estimator's ranked hypotheses, as the tab asks the worker for them
        model = worker.hypotheses()?;
    }
    if panel == Panel::Posterior {
        // posteriors of the best-scored surviving matches (inliers under GT first)
        let mut order: Vec<usize> = (0..model.matches.len()).collect();
        order.sort_by(|&x, &y| {
            let (mx, my) = (&model.matches[x], &model.matches[y]);
            (my.survived, my.inlier_gt, my.score)
                .partial_cmp(&(mx.survived, mx.inlier_gt, mx.score))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        let srcs: Vec<usize> = order
            .iter()
            .take(6)
            .map(|&i| model.matches[i].src)
            .collect();
        for s in srcs {
            model = worker.inspect_point(s)?;
        }
    }
    let params = worker.params().clone();
    let (mode, count, only, align) = (a.match_colors, a.matches, a.only_survivors, a.alignment);
    let (cloud_mode, depth_frames) = (a.cloud_colors, a.depth_frames);
    let (view_pair, depth_cue, sort) = (a.view_pair, a.depth_cue, a.sort);
    let rasterizer = a.rasterizer;
    if let Some((i, j)) = view_pair {
        let (ks, kt) = (model.source_views.len(), model.target_views.len());
        if i >= ks || j >= kt {
            return Err(Error::Invalid(format!(
                "--view-pair {i},{j}: the pair has {ks} source and {kt} target views"
            )));
        }
    }
    crate::io::output::prepare(&a.out, crate::io::output::OutputKind::Png, a.force)?;
    crate::app::headless::render_screenshot_with(
        &model,
        panel,
        (a.width, a.height),
        &a.out,
        |app| {
            app.params = params;
            app.ui_state.match_mode = mode;
            app.ui_state.match_count = count;
            // the views get the whole height (the 3D overlay has its own screenshot)
            app.ui_state.show_3d_below_views = false;
            app.ui_state.only_survivors = only;
            let p = app.view3d_prefs_mut();
            p.show_estimated = matches!(align, Alignment::Estimated | Alignment::All);
            p.show_ground_truth = matches!(align, Alignment::Gt | Alignment::All);
            p.show_initial = matches!(align, Alignment::Initial | Alignment::All);
            (p.source_mode, p.target_mode) = (cloud_mode, cloud_mode);
            p.depth_cue = depth_cue;
            p.rasterizer = rasterizer;
            app.show_depth_frames(depth_frames);
            app.show_view_pair(view_pair);
            if let Some(s) = sort {
                app.ui_state.pair_sort = s;
            }
        },
    )
    .map_err(|e| Error::Invalid(format!("cannot render the screenshot headless: {e}")))?;
    eprintln!("wrote {}", a.out.display());
    Ok(())
}
