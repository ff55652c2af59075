//! One settings story for the inspector: the demo's protocol stays with the demo, `inspect`
//! options replace only what they name, every row knows its settings, an image branch that
//! cannot run is an error (never a geometry-only result under its label), and what the
//! inspector shows equals what `register` computes with the same flags.
#![cfg(feature = "gui")]

use crate::common::{self, demo_manifest, json_close, pose_max_diff};

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cgenreg::app::model::{InspectorModel, PairStatus, SettingsTag};
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{paper_defaults, spawn_worker, Command, OpenKind, WorkerEvent, WorkerHandle};
use cgenreg::cache::Cache;
use cgenreg::dataset::manifest::Dataset;
use cgenreg::pipeline::{RegisterParams, Registration, WfmSpec};

fn manifest(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("assets/manifests/{name}.toml"))
}

/// The data root, exported as `$CGENREG_DATA` for the bundled manifests (None: skip).
fn data() -> Option<PathBuf> {
    let root = cgenreg::testing::test_data_root()?;
    common::export_data_env(&root);
    Some(root)
}

/// `cgenreg inspect ARGS`'s named options and the settings they give over `saved`.
fn inspect_settings(
    saved: Option<&RegisterParams>,
    args: &[&str],
) -> cgenreg::Result<RegisterParams> {
    use clap::{CommandFactory, FromArgMatches};
    let argv: Vec<&str> = ["cgenreg", "inspect"].iter().chain(args).copied().collect();
    let m = cgenreg::cli::Cli::command()
        .try_get_matches_from(argv)
        .unwrap();
    let cli = cgenreg::cli::Cli::from_arg_matches(&m).unwrap();
    let sub = m.subcommand_matches("inspect").unwrap();
    let named = cgenreg::cli::gui::named_options(sub);
    let Some(cgenreg::cli::Command::Inspect(a)) = cli.command else {
        panic!("not inspect")
    };
    // an Option of flattened options is None when none of them is given
    let (dp, di) = default_args();
    let (p, i) = (a.pipeline.unwrap_or(dp), a.image.unwrap_or(di));
    cgenreg::cli::gui::inspect_settings(saved, &p, &i, &named, None).map(|(p, _)| p)
}

#[derive(clap::Parser)]
struct Flags {
    #[command(flatten)]
    p: cgenreg::cli::args::PipelineArgs,
    #[command(flatten)]
    i: cgenreg::cli::args::ImageArgs,
}

fn default_args() -> (
    cgenreg::cli::args::PipelineArgs,
    cgenreg::cli::args::ImageArgs,
) {
    use clap::Parser;
    let a = Flags::try_parse_from(["cgenreg"]).unwrap();
    (a.p, a.i)
}

/// `register`'s parameters for the same flags.
fn register_params(args: &[&str]) -> RegisterParams {
    use clap::Parser;
    let argv: Vec<&str> = ["cgenreg"].iter().chain(args).copied().collect();
    let a = Flags::try_parse_from(argv).unwrap();
    let mut params = a.p.to_params(a.i.wfm.is_some(), None);
    params.image = a.i.to_image_params().unwrap();
    params
}

#[test]
fn inspect_options_replace_only_the_settings_they_name() {
    // saved: oracle, K = 2, L = 8, m = 1, tau_img 0.3, voxel 4 cm
    let mut saved = register_params(&[
        "--wfm", "oracle", "--k", "2", "--frames", "8", "--margin", "1",
    ]);
    saved.voxel = 0.04;
    saved.fusion.calibration_img = saved.fusion.calibration_img.with_tau(0.3);
    // no options: exactly the saved settings
    assert_eq!(inspect_settings(Some(&saved), &[]).unwrap(), saved);
    // --k 4 (even though 4 is its default) changes K and nothing else
    let p = inspect_settings(Some(&saved), &["--k", "4"]).unwrap();
    let mut want = saved.clone();
    want.image.as_mut().unwrap().k = 4;
    assert_eq!(p, want);
    // --voxel keeps the image branch and its L, m, K
    let p = inspect_settings(Some(&saved), &["--voxel", "0.05"]).unwrap();
    assert_eq!(p.voxel, 0.05);
    assert_eq!(p.image, saved.image);
    assert_eq!(p.fusion, saved.fusion);
    // --wfm builtin: the backend only, the saved L, m, K stay
    let p = inspect_settings(Some(&saved), &["--wfm", "builtin"]).unwrap();
    let ib = p.image.unwrap();
    assert_eq!(ib.backend, WfmSpec::Builtin);
    assert_eq!((ib.frames_per_fragment, ib.margin, ib.k), (8, 1, 2));
    // nothing saved: the paper's defaults, which are `register`'s without options
    assert_eq!(inspect_settings(None, &[]).unwrap().image, None);
    let p = inspect_settings(None, &["--wfm", "oracle"]).unwrap();
    assert_eq!(p, register_params(&["--wfm", "oracle"]));
    // an image option while the branch is off is an error naming it, not ignored
    let e = inspect_settings(None, &["--k", "3"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("--k") && e.contains("--wfm"), "{e}");
}

#[test]
fn view_controls_cannot_make_k_too_large_for_l_and_m() {
    use cgenreg::app::controls::clamp_views;
    let mut ib = cgenreg::pipeline::ImageBranchParams {
        k: 8,
        frames_per_fragment: 8,
        margin: 1,
        ..Default::default()
    };
    clamp_views(&mut ib);
    assert_eq!(ib.k, 7, "K <= L - m");
    ib.margin = 20;
    clamp_views(&mut ib);
    assert_eq!((ib.margin, ib.k), (7, 1), "m < L, K >= 1");
    // whatever the controls leave is a valid view selection
    for l in 2..12 {
        for m in 0..14 {
            for k in 0..14 {
                let mut ib = cgenreg::pipeline::ImageBranchParams {
                    k,
                    frames_per_fragment: l,
                    margin: m,
                    ..Default::default()
                };
                clamp_views(&mut ib);
                cgenreg::wfm::select_views(2 * l, l, ib.margin, ib.k).unwrap();
            }
        }
    }
}

/// Events until a model whose current pair finished (done or failed); the settings events
/// seen on the way.
fn wait_model(h: &WorkerHandle, secs: u64) -> (Box<InspectorModel>, Vec<RegisterParams>) {
    let t0 = Instant::now();
    let mut settings = Vec::new();
    while t0.elapsed() < Duration::from_secs(secs) {
        for e in h.poll() {
            match e {
                WorkerEvent::Settings(s) => settings.push(*s),
                WorkerEvent::Model(m) => {
                    let st = m.current_pair.map(|i| m.pairs[i].status.clone());
                    if matches!(st, Some(PairStatus::Done | PairStatus::Failed(_))) {
                        return (m, settings);
                    }
                }
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!("no result from the worker in {secs} s");
}

fn cache_in(dir: &Path) -> Cache {
    Cache::open(dir).unwrap()
}

/// The library's registration of `id` with `params` (what `register --json` prints).
fn library_result(
    manifest: &Path,
    id: &str,
    params: &RegisterParams,
    cache: &Cache,
) -> cgenreg::pipeline::RegistrationResult {
    let pair = Dataset::load(manifest).unwrap().load_pair(id).unwrap();
    Registration::new(params).cache(cache).run(&pair).unwrap()
}

fn assert_same_result(
    what: &str,
    gui: &cgenreg::pipeline::RegistrationResult,
    lib: &cgenreg::pipeline::RegistrationResult,
) {
    assert!(
        pose_max_diff(&gui.target_from_source, &lib.target_from_source) < 1e-9,
        "{what}: pose differs"
    );
    assert_eq!(gui.n_correspondences, lib.n_correspondences, "{what}");
    assert_eq!(gui.n_inliers, lib.n_inliers, "{what}");
    assert_eq!(gui.image_branch, lib.image_branch, "{what}");
}

#[test]
fn the_demo_protocol_stays_with_the_demo() {
    let Some(_) = data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let ds = Dataset::load(&demo_manifest()).unwrap();
    let mut w = PipelineWorker::new(ds, paper_defaults());
    w.set_cache(Some(cache_in(tmp.path())));
    w.enter_demo_protocol();
    let ib = w.params().image.clone().unwrap();
    assert_eq!((ib.frames_per_fragment, ib.margin, ib.k), (8, 1, 2));
    assert_eq!(w.user_params(), &paper_defaults());
    let id = w.pair_ids()[0].clone();
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::SelectPair(id)));
    let (m, _) = wait_model(&h, 300);
    assert!(
        m.demo_protocol.is_some(),
        "the demo says it runs its own protocol"
    );
    assert!(m.branches_ran.as_deref().unwrap().contains("image"));
    // a change made on the demo (a temperature) is the user's and carries over; the
    // protocol's L, m, K and backend do not
    let mut tweaked = cgenreg::app::worker::demo_protocol(&paper_defaults());
    tweaked.fusion.calibration_geo = tweaked.fusion.calibration_geo.with_tau(0.2);
    assert!(h.send(Command::ApplySettings(tweaked.clone())));
    let _ = wait_model(&h, 300);
    // open real data: the paper's defaults come back (with the tweak), as `register` runs them
    let staged = manifest("redkitchen-staged");
    assert!(h.send(Command::Open {
        kind: OpenKind::Manifest,
        paths: vec![staged.clone()],
    }));
    let (m, settings) = wait_model(&h, 600);
    let restored = settings
        .last()
        .expect("the controls hear of the restored settings");
    tweaked.image = None;
    tweaked.fusion.mode = paper_defaults().fusion.mode;
    tweaked.fusion.selection = paper_defaults().fusion.selection;
    assert_eq!(restored, &tweaked);
    assert!(m.demo_protocol.is_none());
    assert_eq!(m.settings.as_ref().unwrap(), &SettingsTag::of(&tweaked));
    assert!(m
        .branches_ran
        .as_deref()
        .unwrap()
        .contains("image branch off"));
    // equal to the library's registration with those settings (`register --tau-geo 0.2`)
    let id = m.pairs[m.current_pair.unwrap()].id.clone();
    let lib = library_result(&staged, &id, &tweaked, &cache_in(tmp.path()));
    let row = &m.pairs[m.current_pair.unwrap()];
    let lib_m = lib.metrics.as_ref().unwrap();
    assert!((row.rre_deg.unwrap() - lib_m.rre_deg).abs() < 1e-9);
    assert_eq!(row.correspondences, Some(lib.n_correspondences));
}

#[test]
fn an_image_branch_that_cannot_run_is_an_error_row_with_its_reason() {
    let Some(_) = data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    // a LiDAR pair has no colour frames: oracle cannot run
    let lidar = manifest("small-gicp-lidar");
    let params = register_params(&["--voxel", "0.5", "--wfm", "oracle"]);
    let mut w = PipelineWorker::new(Dataset::load(&lidar).unwrap(), params.clone());
    w.set_cache(Some(cache_in(tmp.path())));
    let id = w.pair_ids()[0].clone();
    let e = w.run_pair(&id).unwrap_err().to_string();
    assert!(
        e.contains("image branch cannot run") && e.contains("oracle"),
        "{e}"
    );
    // ... naming the scans without RGB and what to use instead
    assert!(
        e.contains("neither scan has real RGB frames") && e.contains("use `builtin`"),
        "{e}"
    );
    assert!(
        w.result().is_none(),
        "no geometry-only result under the oracle label"
    );
    // Run failed/pending: the same error row, stamped with the settings asked for
    let s = w.run_all(
        cgenreg::app::channel::RunSelection::FailedOrPending,
        &mut |_| {},
    );
    assert_eq!(s.errors, s.done);
    let row = &w.pair_rows()[0];
    assert!(matches!(&row.status, PairStatus::Failed(why) if why.contains("oracle")));
    assert_eq!(row.settings.as_ref().unwrap(), &SettingsTag::of(&params));
    // "Run geometry only": the branch off, the pair registers
    let mut geo = params.clone();
    geo.image = None;
    geo.fusion.mode = cgenreg::fusion::FusionMode::GeometryOnly;
    geo.fusion.selection = cgenreg::fusion::Selection::RowNn;
    w.set_params(geo);
    let m = w.run_pair(&id).unwrap();
    assert!(m
        .branches_ran
        .as_deref()
        .unwrap()
        .contains("image branch off"));
    assert_eq!(m.pairs[m.current_pair.unwrap()].status, PairStatus::Done);
}

#[test]
fn rows_of_other_settings_are_stale_and_counted_apart() {
    let Some(_) = data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let staged = manifest("redkitchen-staged");
    let a = paper_defaults();
    let mut w = PipelineWorker::new(Dataset::load(&staged).unwrap(), a.clone());
    w.set_cache(Some(cache_in(tmp.path())));
    let ids = w.pair_ids();
    w.run_pair(&ids[0]).unwrap();
    // a settings change, then another pair
    let mut b = a.clone();
    b.voxel = 0.06;
    w.set_params(b.clone());
    let m = w.run_pair(&ids[1]).unwrap();
    let (ta, tb) = (SettingsTag::of(&a), SettingsTag::of(&b));
    assert_ne!(ta.id, tb.id);
    assert_eq!(m.pairs[0].settings.as_ref(), Some(&ta));
    assert_eq!(m.pairs[1].settings.as_ref(), Some(&tb));
    assert!(cgenreg::app::tabs::pairs::is_stale(
        &m.pairs[0],
        Some(&tb.id)
    ));
    assert!(!cgenreg::app::tabs::pairs::is_stale(
        &m.pairs[1],
        Some(&tb.id)
    ));
    let rows: Vec<usize> = (0..m.pairs.len()).collect();
    let s = cgenreg::app::tabs::pairs::summary(&m, &rows, Some(&tb.id));
    assert!(s.contains("1 stale"), "{s}");
    assert!(
        s.starts_with(&format!(
            "{} pairs with the current settings",
            m.pairs.len() - 1
        )),
        "{s}"
    );
    // the summary counts one settings set: pair 1's outcome only
    let one = if m.pairs[1].success == Some(true) {
        "1 success"
    } else {
        "1 failure"
    };
    assert!(s.contains(one), "{s}");
    // Run failed/pending re-runs the stale row
    assert!(w
        .selected_pairs(cgenreg::app::channel::RunSelection::FailedOrPending)
        .contains(&ids[0]));
}

/// A few pairs across the staged, redkitchen-rgbd and LiDAR manifests under geometry only,
/// oracle and built-in (where the data has what they need): the inspector's result is the
/// library's (`register`'s) with the same flags. Kept small for CI.
#[test]
fn the_inspector_computes_what_register_computes() {
    let Some(_) = data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let cases: &[(&str, Option<&str>, &[&str])] = &[
        // geometry only on the staged pair; the rgbd pair's fragments are rebuilt once and
        // shared by its two image-branch cases (the costliest part of this test), whose
        // keypoints are on a 10 cm grid (what is compared does not depend on their number)
        ("redkitchen-staged", None, &[]),
        (
            "redkitchen-rgbd",
            None,
            &["--wfm", "oracle", "--voxel", "0.1"],
        ),
        (
            "redkitchen-rgbd",
            None,
            &[
                "--wfm", "builtin", "--frames", "8", "--margin", "1", "--k", "2", "--voxel", "0.1",
            ],
        ),
        (
            "small-gicp-lidar",
            None,
            &[
                "--voxel", "0.5", "--wfm", "builtin", "--k", "1", "--frames", "8", "--margin", "1",
            ],
        ),
    ];
    for (name, pair, flags) in cases {
        let t = Instant::now();
        let m = manifest(name);
        let params = register_params(flags);
        let mut w = PipelineWorker::new(Dataset::load(&m).unwrap(), params.clone());
        w.set_cache(Some(cache_in(tmp.path())));
        let id = pair
            .map(str::to_string)
            .unwrap_or_else(|| w.pair_ids()[0].clone());
        w.run_pair(&id).unwrap();
        let gui = w.result().unwrap().clone();
        let lib = library_result(&m, &id, &params, &cache_in(tmp.path()));
        assert_same_result(&format!("{name}/{id} {flags:?}"), &gui, &lib);
        eprintln!("{name}/{id} {flags:?}: {:.1} s", t.elapsed().as_secs_f64());
    }
}

/// `screenshot --result-json` writes the result the picture shows, in `register --json`'s
/// format, equal to `register --json`'s with the same flags.
#[test]
fn screenshot_result_json_equals_register_json() {
    let Some(_) = data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let staged = manifest("redkitchen-staged");
    let id = Dataset::load(&staged).unwrap().pairs()[0].id.clone();
    let cache = tmp.path().join("cache");
    let flags = [
        "--manifest",
        staged.to_str().unwrap(),
        "--pair",
        &id,
        "--cache-dir",
        cache.to_str().unwrap(),
    ];
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cgenreg"))
            .env_remove("CGENREG_CACHE")
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).to_string(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        )
    };
    let json = tmp.path().join("result.json");
    let png = tmp.path().join("shot.png");
    let mut shot = vec![
        "screenshot",
        "--panel",
        "3d",
        "--out",
        png.to_str().unwrap(),
        "--result-json",
        json.to_str().unwrap(),
    ];
    shot.extend(flags);
    let (ok, _, err) = run(&shot);
    // without EGL the picture cannot be drawn; the result is written before it
    assert!(
        ok || err.contains("cannot render the screenshot headless"),
        "{err}"
    );
    let mut reg = vec!["register", "--json"];
    reg.extend(flags);
    let (ok, out, err) = run(&reg);
    assert!(ok, "{err}");
    let a: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let b: serde_json::Value = serde_json::from_str(&out).unwrap();
    // the same keys, and the same values for everything but the timings
    let keys = |v: &serde_json::Value| v.as_object().unwrap().keys().cloned().collect::<Vec<_>>();
    assert_eq!(keys(&a), keys(&b));
    for k in keys(&a) {
        if ["timings", "total_ms"].contains(&k.as_str()) {
            continue;
        }
        assert!(json_close(&a[&k], &b[&k]), "{k}: {} vs {}", a[&k], b[&k]);
    }
    // --out into a missing folder is refused, not created
    let missing = tmp.path().join("no-such-dir").join("x.png");
    let mut shot = vec!["screenshot", "--out", missing.to_str().unwrap()];
    shot.extend(flags);
    let (ok, _, err) = run(&shot);
    assert!(!ok && err.contains("does not exist"), "{err}");
    assert!(!missing.parent().unwrap().exists());
}
