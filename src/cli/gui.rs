//! `cgenreg inspect` and `cgenreg screenshot`: the inspector on a dataset pair, in a window or
//! rendered headless to a PNG.

use super::args::{ImageArgs, PipelineArgs};
use crate::app::channel::RunSelection;
use crate::app::pair_order::PairSort;
use crate::app::worker::PipelineWorker;
use crate::app::{Command, MatchColorMode, Panel};
use crate::cli::args::ManifestSettings;
use crate::error::{Error, Result};
use crate::pipeline::RegisterParams;
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
    /// The ids of the options given on the command line (each replaces only its own setting).
    #[arg(skip)]
    pub named: Vec<String>,
}

/// The ids of the options given on the command line (not their defaults).
pub fn named_options(m: &clap::ArgMatches) -> Vec<String> {
    m.ids()
        .filter(|id| {
            matches!(
                m.value_source(id.as_str()),
                Some(
                    clap::parser::ValueSource::CommandLine | clap::parser::ValueSource::EnvVariable
                )
            )
        })
        .map(|id| id.as_str().to_string())
        .collect()
}

/// `base` with the settings of the options in `named` taken from `given` (the parameters the
/// whole command line describes): `inspect --k 8` changes K and nothing else of the saved
/// settings. Options that decide a default of another setting (`--wfm` the selection and
/// the fusion mode, as in `register`) carry it along unless that one is named too.
pub fn apply_named(
    base: &RegisterParams,
    given: &RegisterParams,
    given_image: &crate::pipeline::ImageBranchParams,
    named: &[String],
) -> Result<RegisterParams> {
    let has = |id: &str| named.iter().any(|n| n == id);
    let mut p = base.clone();
    let (f, g) = (&mut p.fusion, &given.fusion);
    if has("voxel") {
        p.voxel = given.voxel;
    }
    if [
        "learned_source",
        "learned_target",
        "geotransformer_pkl",
        "geo_features",
        "spinnet_model",
        "spinnet_keypoints",
    ]
    .iter()
    .any(|id| has(id))
    {
        p.geo_features = given.geo_features.clone();
    }
    if has("reference") {
        *f = *g;
    }
    if has("calibration") || has("tau_img") {
        f.calibration_img = g.calibration_img;
    }
    if has("calibration") || has("tau_geo") {
        f.calibration_geo = g.calibration_geo;
    }
    if has("fusion") {
        f.mode = g.mode;
    }
    if has("prior") {
        f.prior = g.prior;
    }
    if has("selection") || has("topk") {
        f.selection = g.selection;
    }
    if has("estimator") {
        p.estimator = given.estimator.clone();
    }
    // the scale options over the protocol (as `register` applies them over its preset)
    if has("scales") {
        p.scales = given.scales;
    }
    if has("inlier_threshold") {
        p.inlier_threshold = given.inlier_threshold;
    }
    if let (crate::estimate::EstimatorKind::Sc2Pcr(s), crate::estimate::EstimatorKind::Sc2Pcr(gs)) =
        (&mut p.estimator, &given.estimator)
    {
        if has("inlier_threshold") {
            s.inlier_threshold = gs.inlier_threshold;
        }
        if has("d_thre") {
            s.d_thre = gs.d_thre;
        }
    }
    let image_named: Vec<&str> = [
        "wfm_dir",
        "wfm_spec",
        "cosmos_cmd",
        "cosmos_work_dir",
        "cosmos_timeout",
        "prompt_preset",
        "prompt",
        "seed",
        "vfm",
        "vfm_model",
        "k",
        "margin",
        "frames",
        "lift_radius",
        "virtual_camera",
        "lidar_cameras",
        "lidar_origin",
        "dense_stride",
    ]
    .into_iter()
    .filter(|id| has(id))
    .collect();
    if has("wfm") {
        // switching the branch on or off: the selection and fusion defaults follow, as in
        // `register`, unless named
        if !has("selection") && !has("topk") && !has("reference") {
            p.fusion.selection = g.selection;
        }
        if !has("fusion") {
            p.fusion.mode = match given.image {
                None => crate::fusion::FusionMode::default_for(false, false),
                Some(_) => g.mode,
            };
        }
        // the saved image-branch settings stay; only the backend is the one named
        p.image = given.image.as_ref().map(|gb| {
            let mut ib = base.image.clone().unwrap_or_default();
            ib.backend = gb.backend.clone();
            ib
        });
    }
    if image_named.is_empty() {
        return Ok(p);
    }
    let Some(ib) = p.image.as_mut() else {
        return Err(Error::Usage(format!(
            "--{} sets the image branch, which is off (in the saved settings and on the \
             command line): add --wfm oracle|builtin|cached",
            image_named[0].replace('_', "-")
        )));
    };
    let gb = given_image;
    macro_rules! take {
        ($id:literal, $field:ident) => {
            if has($id) {
                ib.$field = gb.$field.clone();
            }
        };
    }
    take!("seed", seed);
    take!("k", k);
    take!("margin", margin);
    take!("frames", frames_per_fragment);
    take!("lift_radius", lift_radius);
    take!("virtual_camera", virtual_camera);
    take!("lidar_cameras", lidar_cameras);
    take!("lidar_origin", lidar_origin);
    take!("dense_stride", dense_stride);
    if has("vfm") || has("vfm_model") {
        ib.vfm = gb.vfm.clone();
    }
    if has("prompt_preset") || has("prompt") {
        ib.prompt = gb.prompt.clone();
    }
    if [
        "wfm_dir",
        "wfm_spec",
        "cosmos_cmd",
        "cosmos_work_dir",
        "cosmos_timeout",
    ]
    .iter()
    .any(|id| has(id))
    {
        if !gb.backend.same_kind(&ib.backend) {
            return Err(Error::Usage(format!(
                "--{} belongs to another WFM backend than the saved one ({}): add --wfm",
                image_named[0].replace('_', "-"),
                ib.backend.label()
            )));
        }
        ib.backend = gb.backend.clone();
    }
    Ok(p)
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
    /// Also write the registration result the picture shows, in `register --json`'s format.
    #[arg(long, value_name = "FILE")]
    pub result_json: Option<PathBuf>,
    #[arg(long, default_value_t = 1600)]
    pub width: u32,
    #[arg(long, default_value_t = 1000)]
    pub height: u32,
    /// Correspondence colours: gt (green inlier / red outlier under ground truth),
    /// categorical or confidence (default: the inspector's, gt).
    #[arg(long, value_enum)]
    pub match_colors: Option<MatchColorMode>,
    /// Number of correspondences drawn, highest fused score first (default: the
    /// inspector's, 150).
    #[arg(long)]
    pub matches: Option<usize>,
    /// Pose the source is drawn under in the 3D view: estimated, gt, initial or all.
    #[arg(long, value_enum, default_value_t = Alignment::Estimated)]
    pub alignment: Alignment,
    /// Draw only the correspondences the estimator kept (SC2-PCR inliers).
    #[arg(long)]
    pub only_survivors: bool,
    /// 3D view: the source beside the target, so correct correspondences are parallel lines.
    #[arg(long)]
    pub side_by_side: bool,
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
    /// Depth cue of the 3D view's points: eye-dome lighting, normal shading or none
    /// (default: the inspector's, edl).
    #[arg(long, value_enum)]
    pub depth_cue: Option<crate::app::render3d::DepthCue>,
    /// Who draws the 3D view's points: auto (CPU splatting under a software GL such as the
    /// headless llvmpipe, GL points on a GPU), gl or cpu.
    #[arg(long, value_enum, default_value = "auto")]
    pub rasterizer: crate::app::render3d::Rasterizer,
    /// Run every pair of the manifest through the worker first, as the pair browser's "Run
    /// all" does (fills the browser and the RRE/RTE plot; a pair that cannot be registered is
    /// an error row), then show --pair.
    #[arg(long, alias = "all-pairs")]
    pub run_all: bool,
    /// With --run-all: run every pair with the paper's defaults (geometry only, v = 5 cm),
    /// then --pair with the settings given: the pair list holds rows of two settings, as
    /// after a settings change.
    #[arg(long, requires = "run_all")]
    pub run_all_defaults: bool,
    /// The pair browser's order: COLUMN[:asc|:desc], COLUMN one of pair, split, status, rre,
    /// rte, inliers, corr, time (e.g. rre:desc, worst RRE first; the default).
    #[arg(long, value_parser = PairSort::parse)]
    pub sort: Option<PairSort>,
    /// The pair browser shows failures and errors above the other rows.
    #[arg(long)]
    pub failures_first: bool,
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

/// An output file's folder must exist: a typo in a path never creates folders silently.
fn check_out_folder(flag: &str, path: &Path) -> Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    match dir {
        Some(d) if !d.is_dir() => Err(Error::Missing(format!(
            "{flag} {}: the folder {} does not exist (create it first)",
            path.display(),
            d.display()
        ))),
        _ => Ok(()),
    }
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

/// The settings `screenshot` runs `pair` of `manifest` with: what the manifest names for the
/// pair (preset, scene description, geometric features) unless an option names its own, the
/// settings `register --manifest --pair` runs it with.
pub fn screenshot_params(
    manifest: Option<&Path>,
    pair: Option<&str>,
    pipeline: &PipelineArgs,
    image: &ImageArgs,
) -> Result<RegisterParams> {
    let settings = match manifest {
        Some(m) => manifest_settings(m, pair)?,
        None => ManifestSettings::default(),
    };
    Ok(image.params_and_cache_for(pipeline, &settings)?.0)
}

fn open(
    manifest: Option<&Path>,
    pair: Option<&str>,
    pipeline: &PipelineArgs,
    image: &ImageArgs,
) -> Result<(PipelineWorker, String)> {
    let params = screenshot_params(manifest, pair, pipeline, image)?;
    open_with(manifest, pair, params, image)
}

/// What the manifest at `path` names for `pair` (its first pair when None): the settings
/// `register --manifest --pair` resolves, through the same function.
pub fn manifest_settings(path: &Path, pair: Option<&str>) -> Result<ManifestSettings> {
    let ds = crate::dataset::manifest::Dataset::load(path)?;
    Ok(
        match pair.or_else(|| ds.pairs().first().map(|p| p.id.as_str())) {
            Some(id) => ManifestSettings::of_pair(&ds, id),
            None => ManifestSettings::of(&ds),
        },
    )
}

fn open_with(
    manifest: Option<&Path>,
    pair: Option<&str>,
    params: RegisterParams,
    image: &ImageArgs,
) -> Result<(PipelineWorker, String)> {
    let manifest = manifest
        .map(Path::to_path_buf)
        .unwrap_or_else(demo_manifest);
    // fragments rebuilt from raw RGB-D frames are kept in the stage cache, as in `register`
    let dataset = crate::dataset::manifest::Dataset::load(&manifest)?
        .with_fragment_cache(image.fragment_cache()?);
    let mut worker = PipelineWorker::new(dataset, params);
    worker.set_cache(image.open_cache()?);
    let ids = worker.pair_ids();
    let id = match pair {
        Some(p) if ids.iter().any(|i| i == p) => p.to_string(),
        Some(p) => {
            return Err(Error::Missing(format!(
                "{}: no pair {p:?}; pairs: {}",
                manifest.display(),
                ids.join(", ")
            )))
        }
        None => ids.first().cloned().ok_or_else(|| {
            Error::Missing(format!(
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

/// The settings `inspect` starts with: the saved ones (else the paper's defaults), under the
/// protocol of the data opened (`manifest`: `--preset` when named, else what the manifest names
/// for the pair, else indoor, as `register` resolves it), with each option named on the command
/// line replacing its own setting. The notice says when the protocol changed.
pub fn inspect_settings(
    saved: Option<&RegisterParams>,
    pipeline: &PipelineArgs,
    image: &ImageArgs,
    named: &[String],
    manifest: Option<(&str, &ManifestSettings)>,
) -> Result<(RegisterParams, Option<String>)> {
    let mut base = saved.cloned().unwrap_or_else(crate::app::paper_defaults);
    let notice = match (
        named.iter().any(|n| n == "preset"),
        pipeline.preset,
        manifest,
    ) {
        (true, Some(pr), _) => {
            pr.apply(&mut base);
            None
        }
        (_, _, Some((what, m))) => {
            crate::pipeline::manifest_settings::adopt_preset(&mut base, what, m)
        }
        _ => None,
    };
    // the geometric features and the scene the manifest names, as `register` and Open… take
    // them (a named option replaces them below)
    if let Some(g) = manifest.and_then(|(_, m)| m.geo_features) {
        base.geo_features = crate::pipeline::params::GeoFeatureSource::from(g);
    }
    let scene = manifest.and_then(|(_, m)| m.scene_prompt.as_deref());
    if let (Some(ib), Some(scene)) = (base.image.as_mut(), scene) {
        let default = crate::wfm::PromptPreset::SceneSpecific.default_scene();
        if ib.prompt.scene.trim() == default.trim() {
            ib.prompt.scene = scene.to_owned();
        }
    }
    let mut given = pipeline.to_params(image.wfm.is_some(), None);
    given.image = image.to_image_params()?;
    // the image options' values even without --wfm (they then change the saved branch)
    let mut with_wfm = image.clone();
    if with_wfm.wfm.is_none() {
        with_wfm.wfm = Some(crate::pipeline::params::WfmSpec::Builtin);
    }
    let given_image = with_wfm.to_image_params()?.unwrap_or_default();
    Ok((apply_named(&base, &given, &given_image, named)?, notice))
}

pub fn run_inspect(a: InspectArgs) -> Result<()> {
    let (dp, di) = default_args();
    let pipeline = a.pipeline.unwrap_or(dp);
    let image = a.image.unwrap_or(di);
    let settings_path = crate::app::default_settings_path();
    let saved = settings_path
        .as_deref()
        .filter(|p| p.is_file())
        .map(|p| crate::app::load_persisted(p).0.params);
    // the data opened now: a manifest, or the demo (not at a relaunch that reopens the data of
    // last time: that open resolves its protocol, as Open… does)
    let reopens = a.manifest.is_none()
        && !a.demo
        && matches!(
            crate::app::startup_commands(settings_path.as_deref(), "")[..],
            [Command::OpenOrFallback { .. }]
        );
    let opened = match &a.manifest {
        Some(m) => Some(m.clone()),
        None if !reopens => Some(demo_manifest()),
        None => None,
    };
    let ms = match &opened {
        Some(m) => Some((
            m.display().to_string(),
            manifest_settings(m, a.pair.as_deref())?,
        )),
        None => None,
    };
    let (params, notice) = inspect_settings(
        saved.as_ref(),
        &pipeline,
        &image,
        &a.named,
        ms.as_ref().map(|(w, m)| (w.as_str(), m)),
    )?;
    let (mut worker, id) = open_with(a.manifest.as_deref(), a.pair.as_deref(), params, &image)?;
    if a.manifest.is_none() {
        // the bundled demo runs under its own protocol (8 frames per sequence); other data
        // opened later gets the settings above back
        worker.enter_demo_protocol();
    }
    let model = worker.initial_model(Some(&id));
    // Without an explicit dataset, the data opened last time comes back (the demo when that
    // fails); `screenshot` and the tests never read the settings file.
    let initial = if a.manifest.is_none() && !a.demo {
        crate::app::startup_commands(settings_path.as_deref(), &id)
    } else {
        vec![Command::SelectPair(id)]
    };
    // the controls show what the worker runs
    let worker_settings = Some(worker.params().clone());
    let compare = a.compare.map(|v| (v[0].clone(), v[1].clone()));
    crate::app::run_gui_configured(model, Box::new(worker), initial, worker_settings, |app| {
        if let Some(n) = notice {
            app.push_log(crate::app::LogLevel::Warn, n);
        }
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
        crate::app::tabs::compare::load_comparison(&runs[0], &runs[1]).map_err(Error::Invalid)?;
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
        let mut st = crate::app::tabs::compare::CompareTab::default();
        st.set_loaded(loaded.clone());
        st.rows()
    };
    let selected = match &a.compare_pair {
        Some(id) if c.pairs.iter().any(|p| &p.id == id) => Some(id.clone()),
        Some(id) => {
            return Err(Error::Missing(format!(
                "--compare-pair {id:?}: not a pair of both runs"
            )))
        }
        None => rows.first().map(|&i| c.pairs[i].id.clone()),
    };
    eprint!("{}", crate::report::compare::table(c));
    // the controls show what the worker would run (nothing runs for this screenshot)
    let params = worker.params().clone();
    let png =
        crate::app::headless::render_screenshot_png(&model, panel, (a.width, a.height), |app| {
            app.params = params;
            app.tabs.compare.set_loaded(loaded);
            app.tabs.compare.selected = selected;
        })
        .map_err(|e| Error::Invalid(format!("cannot render the screenshot headless: {e}")))?;
    crate::io::output::write(&a.out, crate::io::output::OutputKind::Png, a.force, &png)?;
    eprintln!("wrote {}", a.out.display());
    Ok(())
}

pub fn run_screenshot(a: ScreenshotArgs) -> Result<()> {
    // before the work, and again right before the write below
    crate::io::output::prepare(&a.out, crate::io::output::OutputKind::Png, a.force)?;
    if let Some(p) = &a.result_json {
        crate::io::output::prepare(p, crate::io::output::OutputKind::ResultJson, a.force)?;
    }
    let panel = Panel::from_name(&a.panel).ok_or_else(|| {
        Error::Param(format!(
            "--panel {:?}: expected pairs, views, 3d, posterior, plots, stages, compare or hypotheses",
            a.panel
        ))
    })?;
    match (&a.compare, panel) {
        (Some(runs), Panel::Compare) => return run_compare_screenshot(&a, runs, panel),
        (Some(_), _) => {
            return Err(Error::Usage(
                "--compare renders the Compare tab: use it with --panel compare".into(),
            ))
        }
        (None, Panel::Compare) => {
            return Err(Error::Usage(
                "--panel compare needs two runs: --compare A.json B.json".into(),
            ))
        }
        (None, _) => {}
    }
    for (flag, path) in
        std::iter::once(("--out", &a.out)).chain(a.result_json.iter().map(|p| ("--result-json", p)))
    {
        check_out_folder(flag, path)?;
    }
    let (mut worker, id) = open(
        a.manifest.as_deref(),
        a.pair.as_deref(),
        &a.pipeline,
        &a.image,
    )?;
    if a.run_all {
        let t = std::time::Instant::now();
        let asked = worker.params().clone();
        if a.run_all_defaults {
            worker.set_params(crate::app::paper_defaults());
        }
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
        // the pair browser's summary rows, as `bench` prints them (the same function)
        let current = crate::app::model::SettingsTag::of(worker.params()).id;
        let (rows, _) = crate::app::triage::summary_rows(worker.pair_rows(), Some(&current));
        crate::cli::bench::print_field_table(&rows);
        worker.set_params(asked);
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
    if let Some(path) = &a.result_json {
        // the result the picture shows, as `register --json` prints it
        let r = worker
            .result()
            .ok_or_else(|| Error::Missing(format!("{id}: no registration result to write")))?;
        let text = serde_json::to_string_pretty(r)
            .map_err(|e| Error::Encode(format!("serialising the result: {e}")))?;
        crate::io::output::write(
            path,
            crate::io::output::OutputKind::ResultJson,
            a.force,
            format!("{text}\n").as_bytes(),
        )?;
        eprintln!("wrote {}", path.display());
    }
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
    let (cloud_mode, depth_frames, side) = (a.cloud_colors, a.depth_frames, a.side_by_side);
    let (view_pair, depth_cue, sort) = (a.view_pair, a.depth_cue, a.sort);
    let failures_first = a.failures_first;
    let rasterizer = a.rasterizer;
    if let Some((i, j)) = view_pair {
        let (ks, kt) = (model.source_views.len(), model.target_views.len());
        if i >= ks || j >= kt {
            return Err(Error::Param(format!(
                "--view-pair {i},{j}: the pair has {ks} source and {kt} target views"
            )));
        }
    }
    let png =
        crate::app::headless::render_screenshot_png(&model, panel, (a.width, a.height), |app| {
            app.params = params;
            // unset options keep the inspector's own defaults (one set for both)
            if let Some(m) = mode {
                app.ui_state.match_mode = m;
            }
            if let Some(n) = count {
                app.ui_state.match_count = n;
            }
            app.ui_state.only_survivors = only;
            let p = app.view3d_prefs_mut();
            p.show_estimated = matches!(align, Alignment::Estimated | Alignment::All);
            p.show_ground_truth = matches!(align, Alignment::Gt | Alignment::All);
            p.show_initial = matches!(align, Alignment::Initial | Alignment::All);
            (p.source_mode, p.target_mode) = (cloud_mode, cloud_mode);
            if let Some(c) = depth_cue {
                p.depth_cue = c;
            }
            p.side_by_side = side;
            p.rasterizer = rasterizer;
            app.show_depth_frames(depth_frames);
            app.show_view_pair(view_pair);
            if let Some(s) = sort {
                app.ui_state.pair_sort = s;
            }
            app.tabs.pairs.filter.failures_first = failures_first;
        })
        .map_err(|e| Error::Invalid(format!("cannot render the screenshot headless: {e}")))?;
    // checked again and written atomically: a link planted while the pair ran is refused
    crate::io::output::write(&a.out, crate::io::output::OutputKind::Png, a.force, &png)?;
    eprintln!("wrote {}", a.out.display());
    Ok(())
}
