//! Snapshot tests of the inspector's panels (3D included) with egui_kittest and a glow
//! renderer on a surfaceless EGL context (wgpu would skip the 3D paint callback).
//! Update the images with `UPDATE_SNAPSHOTS=1 cargo test --test it gui_snapshots::`.
#![cfg(feature = "gui")]

use std::sync::{Arc, Mutex};

use cgenreg::app::channel::{spawn_worker, Command, EventSink, Worker};
use cgenreg::app::colormap::{SOURCE_RGB, TARGET_RGB};
use cgenreg::app::headless::{render_screenshot, HeadlessGl};
use cgenreg::app::render3d::{DepthCue, Rasterizer};
use cgenreg::app::{App, InspectorModel, Panel};
use cgenreg::wfm::PromptPreset;
use eframe::egui;
use egui_kittest::kittest::Queryable;
use egui_kittest::{Harness, TestRenderer};

struct GlRenderer(HeadlessGl);

impl TestRenderer for GlRenderer {
    fn handle_delta(&mut self, delta: &mut egui::TexturesDelta) {
        self.0.update_textures(delta);
    }
    fn render(
        &mut self,
        ctx: &egui::Context,
        output: &egui::FullOutput,
    ) -> Result<image::RgbaImage, String> {
        let ppp = output.pixels_per_point;
        let r = ctx.content_rect();
        let size = (
            (r.width() * ppp).round() as u32,
            (r.height() * ppp).round() as u32,
        );
        self.0.resize(size)?;
        self.0
            .paint(ctx, output.shapes.clone(), ppp, true)?
            .ok_or_else(|| "no image".into())
    }
}

/// The EGL renderer, or None (skip) when this machine has no EGL; under CI it must exist.
fn renderer() -> Option<GlRenderer> {
    match HeadlessGl::new((1280, 800)) {
        Ok(gl) => Some(GlRenderer(gl)),
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => panic!("CI=true but no EGL: {e}"),
        Err(e) => {
            eprintln!("skipping GUI snapshot test: {e}");
            None
        }
    }
}

fn harness(app: App) -> Option<Harness<'static, App>> {
    let r = renderer()?;
    let h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .with_pixels_per_point(1.0)
        .with_theme(egui::Theme::Dark)
        .renderer(r)
        .build_ui_state(|ui, app: &mut App| app.show(ui), app);
    Some(h)
}

fn demo_app() -> App {
    let mut app = App::new(InspectorModel::demo(), None, None);
    app.allow_dialogs = false;
    app
}

fn snapshot_panel(panel: Panel, name: &str) {
    let mut app = demo_app();
    app.ui_state.tab = panel;
    let Some(mut h) = harness(app) else { return };
    h.run_steps(4);
    h.snapshot(name);
}

#[test]
fn snapshot_views() {
    snapshot_panel(Panel::Views, "views");
}

#[test]
fn snapshot_3d() {
    snapshot_panel(Panel::View3d, "view3d");
}

#[test]
fn snapshot_posterior() {
    snapshot_panel(Panel::Posterior, "posterior");
}

#[test]
fn snapshot_plots() {
    snapshot_panel(Panel::Plots, "plots");
}

#[test]
fn snapshot_stages() {
    snapshot_panel(Panel::Stages, "stages");
}

/// The Compare tab over two real bench runs of docs/ablation: FPFH NN (A) against oracle RGB
/// + XFeat with FPFH, Noisy-AND, NN (B), the first row (flipped first) selected.
#[test]
fn snapshot_compare() {
    use cgenreg::app::tabs::compare::load_comparison;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/ablation");
    let mut l = load_comparison(
        &dir.join("fpfh-nn.json"),
        &dir.join("oracle-noisy-and-nn.json"),
    )
    .unwrap();
    // whether run B's VFM model file exists depends on the machine: not in the image
    l.b.missing.clear();
    let mut app = demo_app();
    app.ui_state.tab = Panel::Compare;
    app.tabs.compare.set_loaded(l);
    let first = app.tabs.compare.rows()[0];
    let id = app.tabs.compare.loaded.as_ref().unwrap().comparison.pairs[first]
        .id
        .clone();
    app.tabs.compare.selected = Some(id);
    let Some(mut h) = harness(app) else { return };
    h.run_steps(4);
    h.snapshot("compare");
}

/// The hypothesis browser on the demo with its UI fixture list: selecting a row shows that
/// hypothesis in the 3D view (its pose, only its consensus drawn).
#[test]
fn snapshot_hypotheses() {
    use cgenreg::app::model::HypothesisList;
    let mut model = InspectorModel::demo();
    model.hypotheses = Some(HypothesisList::fixture(&model));
    let mut app = App::new(model, None, None);
    app.allow_dialogs = false;
    app.ui_state.tab = Panel::Hypotheses;
    let Some(mut h) = harness(app) else { return };
    h.run_steps(3);
    h.get_by_label("#2").click();
    h.run_steps(3);
    let sel = h
        .state()
        .ui_state
        .hypothesis
        .clone()
        .expect("a hypothesis selected");
    assert_eq!(sel.rank, 2);
    let list = h.state().model().hypotheses.clone().unwrap();
    assert_eq!(sel.pose, list.rows[1].pose);
    let n_in = sel.inlier.iter().filter(|x| **x).count();
    assert_eq!(n_in, list.rows[1].consensus);
    h.snapshot("hypotheses");
    // clicking it again clears the selection
    h.get_by_label("#2").click();
    h.run_steps(2);
    assert!(h.state().ui_state.hypothesis.is_none());
}

/// "Save plots (PNG + CSV)": every plot as a PNG cropped from the window's screenshot (the
/// headless renderer answers screenshot requests as eframe does) and its data as CSV.
#[test]
fn plots_save_as_png_and_csv() {
    use cgenreg::app::headless::HeadlessRenderer;
    use cgenreg::app::tabs::plots::PLOT_NAMES;
    if renderer().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("plots");
    let mut r = HeadlessRenderer::new(InspectorModel::demo(), (1280, 800)).unwrap();
    r.app.ui_state.tab = Panel::Plots;
    r.settled_frame().unwrap();
    r.app.tabs.plots.save_dir = out.display().to_string();
    r.app.tabs.plots.save_now = true;
    for _ in 0..4 {
        r.frame(false).unwrap();
    }
    assert!(
        r.app.tabs.plots.pending_png.is_none(),
        "the screenshot never came"
    );
    for name in PLOT_NAMES {
        let csv = std::fs::read_to_string(out.join(format!("{name}.csv"))).unwrap();
        assert!(csv.lines().count() >= 1, "{name}.csv is empty");
        let png = image::open(out.join(format!("{name}.png"))).unwrap();
        let rect = r
            .app
            .tabs
            .plots
            .rects
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap()
            .1;
        assert!(
            (png.width() as f32 - rect.width()).abs() <= 1.0
                && (png.height() as f32 - rect.height()).abs() <= 1.0,
            "{name}.png is {}x{}, the plot {rect:?}",
            png.width(),
            png.height()
        );
    }
    // the demo's pairs are in the per-pair CSV, one row each
    let per_pair = std::fs::read_to_string(out.join("rre_rte_per_pair.csv")).unwrap();
    assert_eq!(
        per_pair.lines().count(),
        1 + InspectorModel::demo().pairs.len()
    );
    assert!(r
        .app
        .tabs
        .plots
        .last_save
        .as_deref()
        .unwrap()
        .contains("PNG"));
}

#[test]
fn snapshot_pairs() {
    snapshot_panel(Panel::Pairs, "pairs");
}

/// The pair browser after a run (the demo's filled rows): "Run all" and "Run failed/pending"
/// (in the side panel and the tab) send their commands, a header click sorts by its column (again: reversed), j opens the
/// next pair of the order, and during a run the progress bar and Cancel are shown (snapshot)
/// and Cancel reaches the worker.
#[test]
fn pairs_tab_runs_all_sorts_navigates_and_cancels() {
    use cgenreg::app::channel::{RunProgress, RunSelection};
    use cgenreg::app::tabs::pairs::{visible_pairs, PairColumn, PairSort};
    let seen = Arc::new(Mutex::new(Vec::new()));
    let handle = spawn_worker(Box::new(Recorder(seen.clone())), None);
    let mut app = App::new(InspectorModel::demo(), Some(handle), None);
    app.allow_dialogs = false;
    app.ui_state.tab = Panel::Pairs;
    let Some(mut h) = harness(app) else { return };
    h.run_steps(2);
    let wait_for = |seen: &Arc<Mutex<Vec<Command>>>, c: &Command| {
        let t0 = std::time::Instant::now();
        while !seen.lock().unwrap().contains(c) {
            assert!(
                t0.elapsed().as_secs() < 10,
                "{c:?} never reached the worker"
            );
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    };
    // the side panel's and the tab's: the same command
    h.get_all_by_label("Run all").next().unwrap().click();
    h.run_steps(2);
    wait_for(&seen, &Command::RunAll(RunSelection::All));
    h.get_all_by_label("Run failed/pending")
        .next()
        .unwrap()
        .click();
    h.run_steps(2);
    wait_for(&seen, &Command::RunAll(RunSelection::FailedOrPending));
    // header clicks: a metric starts worst (largest) first, a second click reverses
    h.get_by_label("time s").click();
    h.run_steps(2);
    let time_desc = PairSort {
        column: PairColumn::Time,
        descending: true,
    };
    assert_eq!(h.state().ui_state.pair_sort, time_desc);
    h.get_by_label("time s v").click();
    h.run_steps(2);
    assert!(!h.state().ui_state.pair_sort.descending);
    // j: the pair after the current one in this order
    let m = h.state().model().clone();
    let order = visible_pairs(
        &m.pairs,
        &h.state().tabs.pairs.filter,
        h.state().ui_state.pair_sort,
    );
    let at = order
        .iter()
        .position(|&i| Some(i) == m.current_pair)
        .unwrap();
    let next = m.pairs[order[at + 1]].id.clone();
    h.key_press(egui::Key::J);
    h.run_steps(2);
    wait_for(&seen, &Command::SelectPair(next.clone()));
    // n: the next failure of this order after the pair just asked for
    let from = m.pairs.iter().position(|p| p.id == next);
    let failure = cgenreg::app::triage::next_failure(&m.pairs, &order, from, true, None).unwrap();
    h.key_press(egui::Key::N);
    h.run_steps(2);
    wait_for(&seen, &Command::SelectPair(m.pairs[failure].id.clone()));
    // a run in progress: bar, Cancel, the running row
    h.state_mut().ui_state.pair_sort = PairSort::WORST_RRE;
    let pair = m.pairs[8].id.clone();
    h.state_mut().tabs.pairs.progress = Some(RunProgress {
        done: 5,
        total: 9,
        pair: pair.clone(),
        row: None,
        finished: false,
        cancelled: false,
    });
    h.state_mut().set_model(m);
    h.run_steps(4);
    h.snapshot("pairs-running");
    h.get_all_by_label("Cancel").next().unwrap().click();
    h.run_steps(2);
    wait_for(&seen, &Command::Cancel);
}

struct Recorder(Arc<Mutex<Vec<Command>>>);
impl Worker for Recorder {
    fn handle(&mut self, command: Command, _events: &EventSink) {
        self.0.lock().unwrap().push(command);
    }
}

/// What a recording worker was sent.
type Commands = Arc<Mutex<Vec<Command>>>;

/// Waits (up to 10 s) until `cond` holds: the recording worker runs on its own thread, so a
/// command the UI sent is in its list a little later, later still on a loaded machine. The
/// caller asserts afterwards.
fn eventually(cond: impl Fn() -> bool) {
    let t0 = std::time::Instant::now();
    while !cond() && t0.elapsed() < std::time::Duration::from_secs(10) {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// The demo app whose worker records the commands it is sent (they are not run), two frames in.
fn recording_harness() -> Option<(Harness<'static, App>, Commands)> {
    let seen = Arc::new(Mutex::new(Vec::new()));
    let handle = spawn_worker(Box::new(Recorder(seen.clone())), None);
    let mut app = App::new(InspectorModel::demo(), Some(handle), None);
    app.allow_dialogs = false;
    let mut h = harness(app)?;
    h.run_steps(2);
    Some((h, seen))
}

#[test]
fn tabs_and_controls_drive_the_ui_and_the_worker() {
    let Some((mut h, seen)) = recording_harness() else {
        return;
    };
    // tabs switch panels
    h.get_by_label("3D").click();
    h.run_steps(2);
    assert_eq!(h.state().ui_state.tab, Panel::View3d);
    h.get_by_label("Reset camera");
    h.get_by_label("Plots").click();
    h.run_steps(2);
    assert_eq!(h.state().ui_state.tab, Panel::Plots);
    // a prompt preset re-runs the pipeline through a command, without blocking the UI
    h.get_by_label("Minimal").click();
    h.run_steps(2);
    // a prompt edit is a draft until applied: the parameters keep their prompt, and the
    // "Apply prompt" button is offered
    assert_ne!(
        h.state().image_off.prompt.scene,
        PromptPreset::Minimal.default_scene()
    );
    assert!(h.query_all_by_label("Apply prompt").next().is_some());
    h.run_steps(3);
    assert!(
        !seen
            .lock()
            .unwrap()
            .iter()
            .any(|c| matches!(c, Command::ApplySettings(_))),
        "a prompt edit with the image branch off re-ran the pipeline: {:?}",
        seen.lock().unwrap()
    );
    // other controls are reachable by label
    assert!(h.query_all_by_label("K views").next().is_some());
    h.get_by_label("Match colours");
    // the image branch's generator is a control (geometry only by default)
    h.get_by_label("WFM");
    assert!(h.state().params.image.is_none());
    assert!(h
        .query_all_by_label("Safeguard margin m (frames)")
        .next()
        .is_some());
}

fn count_near(img: &image::RgbaImage, c: [u8; 3], tol: i32) -> usize {
    img.pixels()
        .filter(|p| (0..3).all(|k| (p.0[k] as i32 - c[k] as i32).abs() <= tol))
        .count()
}

/// Pixels of `a` and `b` (same size) whose R, G or B differ by more than `tol`.
fn differing_pixels(a: &image::RgbaImage, b: &image::RgbaImage, tol: i32) -> usize {
    a.pixels()
        .zip(b.pixels())
        .filter(|(p, q)| (0..3).any(|k| (p.0[k] as i32 - q.0[k] as i32).abs() > tol))
        .count()
}

#[test]
fn headless_3d_screenshot_shows_source_and_target_points() {
    if renderer().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("view3d.png");
    render_screenshot(&InspectorModel::demo(), Panel::View3d, (1024, 640), &out).unwrap();
    let img = image::open(&out).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (1024, 640));
    let src = count_near(&img, SOURCE_RGB, 6);
    let tgt = count_near(&img, TARGET_RGB, 6);
    assert!(src > 500, "too few source-coloured pixels: {src}");
    assert!(tgt > 500, "too few target-coloured pixels: {tgt}");
    // and the plots panel has neither (the colours are the 3D view's)
    let out2 = dir.path().join("stages.png");
    render_screenshot(&InspectorModel::demo(), Panel::Stages, (1024, 640), &out2).unwrap();
    let img2 = image::open(&out2).unwrap().to_rgba8();
    assert!(count_near(&img2, TARGET_RGB, 6) < 50);
}

/// Where no native dialog is available (here: dialogs refused, as on a desktop without an
/// xdg portal or zenity), "Open…" shows the built-in browser: a typed, Tab-completed path
/// opens through the worker and the dataset loads.
#[test]
fn the_built_in_browser_opens_a_typed_manifest_and_the_dataset_loads() {
    use cgenreg::app::worker::PipelineWorker;
    use cgenreg::pipeline::RegisterParams;
    let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml");
    let mut params = RegisterParams::default();
    params.fusion.selection = cgenreg::fusion::select::Selection::RowNn;
    let worker = PipelineWorker::open_manifest(&manifest, params).unwrap();
    let handle = spawn_worker(Box::new(worker), None);
    // the app starts empty: only the open fills it
    let mut app = App::new(InspectorModel::default(), Some(handle), None);
    app.allow_dialogs = false;
    let Some(mut h) = harness(app) else { return };
    h.run_steps(2);
    h.get_by_label("Open…").click();
    h.run_steps(2);
    h.get_by_label("Dataset manifest…").click();
    h.run_steps(2);
    assert!(
        h.state().browser.is_some(),
        "the built-in browser did not open"
    );
    // type the folder and the start of the name, complete with Tab
    let field = h.get_by_label("Path");
    field.click();
    h.run_steps(1);
    h.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    h.run_steps(1);
    let partial = format!("{}/de", manifest.parent().unwrap().display());
    h.get_by_label("Path").type_text(&partial);
    h.run_steps(1);
    h.key_press(egui::Key::Tab);
    h.run_steps(2);
    assert_eq!(
        h.state().browser.as_ref().map(|b| b.text.clone()),
        Some(manifest.display().to_string()),
        "Tab did not complete the file name"
    );
    h.get_by_label("Open").click();
    h.run_steps(2);
    assert!(h.state().browser.is_none(), "the browser stayed open");
    // the worker loads the manifest and registers its first pair
    let t0 = std::time::Instant::now();
    loop {
        h.run_steps(1);
        let m = h.state().model();
        if m.current_pair
            .is_some_and(|i| m.pairs[i].status == cgenreg::app::model::PairStatus::Done)
        {
            assert_eq!(
                m.pairs.len(),
                cgenreg::dataset::Dataset::load(&manifest)
                    .unwrap()
                    .pairs()
                    .len()
            );
            assert!(!m.source.is_empty() && !m.target.is_empty());
            break;
        }
        assert!(
            t0.elapsed().as_secs() < 300,
            "the dataset never loaded; log: {:?}",
            h.state().log.iter().map(|l| &l.text).collect::<Vec<_>>()
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// GL points: a still 3D view of 300k points per cloud refined over frames (the interactive
/// default under the GL) ends in the image one complete frame draws; the frames before are
/// partial, and once complete, further frames (which only composite the kept target) do not
/// change it.
#[test]
fn progressive_3d_refinement_ends_in_the_complete_image() {
    use cgenreg::app::headless::HeadlessRenderer;
    if renderer().is_none() {
        return;
    }
    let model = InspectorModel::demo_sized(300_000);
    let size = (640, 400);
    let mut one = HeadlessRenderer::new(model.clone(), size).unwrap();
    one.app.ui_state.tab = Panel::View3d;
    one.app.view3d_prefs_mut().rasterizer = Rasterizer::Gl;
    let complete = one.settled_frame().unwrap();
    drop(one);
    let mut prog = HeadlessRenderer::new(model, size).unwrap();
    prog.app.ui_state.tab = Panel::View3d;
    prog.app.view3d_prefs_mut().rasterizer = Rasterizer::Gl;
    prog.app.set_complete_3d_frames(false);
    let mut frames = Vec::new();
    while frames.len() < 12 {
        frames.push(prog.frame(true).unwrap().unwrap());
        if frames.len() > 2 && !prog.app.view3d_refining() {
            break;
        }
    }
    assert!(
        !prog.app.view3d_refining(),
        "still refining after 12 frames"
    );
    let differ = |a: &image::RgbaImage, b: &image::RgbaImage| differing_pixels(a, b, 2);
    let last = frames.last().unwrap();
    let total = (size.0 * size.1) as usize;
    // equal depths of different points may resolve the other way when drawn in another order
    let d = differ(last, &complete);
    assert!(
        d * 1000 <= total,
        "refined image differs from the complete one in {d} of {total} pixels"
    );
    let first = differ(&frames[0], &complete);
    assert!(
        first > d + total / 200,
        "the first frame is not partial: {first} pixels differ"
    );
    let again = prog.frame(true).unwrap().unwrap();
    assert_eq!(differ(&again, last), 0, "a kept still view changed");
}

/// GL points: a new model with the same clouds (a re-fusion) keeps the camera where the user left it and
/// the drawn still view (no re-upload, no refinement from scratch); new clouds start afresh.
#[test]
fn a_refusion_keeps_the_camera_and_the_drawn_view() {
    use cgenreg::app::headless::HeadlessRenderer;
    if renderer().is_none() {
        return;
    }
    let model = InspectorModel::demo_sized(300_000);
    let mut r = HeadlessRenderer::new(model, (640, 400)).unwrap();
    r.app.ui_state.tab = Panel::View3d;
    r.app.view3d_prefs_mut().rasterizer = Rasterizer::Gl;
    r.app.set_complete_3d_frames(false);
    // until the final frame: past the settle time after a motion, every point drawn
    let settle = |r: &mut HeadlessRenderer| {
        let t = std::time::Instant::now();
        let mut last = None;
        while t.elapsed().as_secs() < 10 {
            last = r.frame(true).unwrap();
            if !r.app.view3d_refining() {
                break;
            }
        }
        assert!(!r.app.view3d_refining(), "still refining after 10 s");
        last.unwrap()
    };
    settle(&mut r);
    r.app.orbit_3d(40.0, 15.0);
    r.frame(true).unwrap();
    let before = settle(&mut r);
    let same = r.app.model().clone();
    r.app.set_model(same.clone());
    let after = r.frame(true).unwrap().unwrap();
    assert!(
        !r.app.view3d_refining(),
        "the same clouds were drawn again from scratch"
    );
    let differ = after
        .pixels()
        .zip(before.pixels())
        .filter(|(p, q)| p != q)
        .count();
    assert_eq!(
        differ, 0,
        "the view changed after a re-fusion with the same result"
    );
    let mut other = same;
    other.target.truncate(other.target.len() - 1);
    r.app.set_model(other);
    // the camera frames the new clouds (a motion), then their still view refines
    let t = std::time::Instant::now();
    r.frame(false).unwrap();
    assert!(
        r.app.view3d_refining(),
        "new clouds drew a final frame at once"
    );
    // after the settle time a 300k-point view takes two frames: partial, then complete
    let mut settled_frames = 0;
    while r.app.view3d_refining() && t.elapsed().as_secs() < 10 {
        let after_settle = t.elapsed() > cgenreg::app::view3d::SETTLE;
        r.frame(false).unwrap();
        settled_frames += after_settle as usize;
    }
    assert!(
        settled_frames >= 2,
        "new clouds did not start a new refinement ({settled_frames} frames after settling)"
    );
}

/// The demo at `n` points per cloud and a copy whose estimate moved by 5 cm; a renderer of
/// the original whose points `rasterizer` draws, refining as the inspector does, past its
/// settle time and complete; and the moved pose's complete still view.
fn moved_pose(
    n: usize,
    size: (u32, u32),
    rasterizer: Rasterizer,
) -> (
    cgenreg::app::headless::HeadlessRenderer,
    InspectorModel,
    image::RgbaImage,
) {
    use cgenreg::app::headless::HeadlessRenderer;
    let model = InspectorModel::demo_sized(n);
    let mut moved = model.clone();
    let est = moved.estimated.expect("the demo has an estimate");
    moved.estimated = Some(nalgebra::Isometry3::translation(0.05, 0.0, 0.0) * est);
    let mut fresh = HeadlessRenderer::new(moved.clone(), size).unwrap();
    fresh.app.ui_state.tab = Panel::View3d;
    fresh.app.view3d_prefs_mut().rasterizer = rasterizer;
    let complete = fresh.settled_frame().unwrap();
    drop(fresh);
    let mut r = HeadlessRenderer::new(model, size).unwrap();
    r.app.ui_state.tab = Panel::View3d;
    r.app.view3d_prefs_mut().rasterizer = rasterizer;
    r.app.set_complete_3d_frames(false);
    let t = std::time::Instant::now();
    while r.app.view3d_refining() || t.elapsed() <= cgenreg::app::view3d::SETTLE {
        r.frame(false).unwrap();
        assert!(t.elapsed().as_secs() < 10, "still refining after 10 s");
    }
    (r, moved, complete)
}

/// GL points: a re-fusion that moves the pose on a still view: the first frame previews the new
/// alignment at the moving budget (straight to the screen, fast), the following frames refine
/// it into the complete image of the new pose. 100k points fit in one still frame
/// (`REFINE_POINTS_PER_FRAME`), so without the preview the first frame would be final.
#[test]
fn a_moved_pose_is_previewed_then_refined_to_the_complete_view() {
    if renderer().is_none() {
        return;
    }
    let size = (640, 400);
    let (mut r, moved, complete) = moved_pose(100_000, size, Rasterizer::Gl);
    r.app.set_model(moved);
    let preview = r.frame(true).unwrap().unwrap();
    assert!(
        r.app.view3d_refining(),
        "a moved pose drew its final frame at once (no preview)"
    );
    let mut last = preview.clone();
    let mut frames = 1;
    while r.app.view3d_refining() && frames < 12 {
        last = r.frame(true).unwrap().unwrap();
        frames += 1;
    }
    assert!(!r.app.view3d_refining(), "still refining after 12 frames");
    let differ = |a: &image::RgbaImage, b: &image::RgbaImage| differing_pixels(a, b, 2);
    let total = (size.0 * size.1) as usize;
    let d = differ(&last, &complete);
    assert!(
        d * 1000 <= total,
        "the refined view differs from the moved pose's complete view in {d} of {total} pixels"
    );
    let p = differ(&preview, &complete);
    assert!(
        p > d,
        "the preview ({p} pixels off) was not a subsample of the complete view ({d})"
    );
}

/// CPU splatting draws what GL points draw: the demo at 100k points per cloud, every depth
/// cue, the same settled frame through llvmpipe's `GL_POINTS` and through `render3d::splat`
/// (composited by the same GL pass). Pixels may differ where llvmpipe snaps vertex positions
/// to its sub-pixel grid (a point's square shifts by a pixel) or where equal depths resolve
/// the other way; anything systematic (rows flipped, a wrong projection, depth or colour
/// convention) changes most of the drawn pixels.
#[test]
fn cpu_splatting_draws_what_gl_points_draw() {
    use cgenreg::app::headless::HeadlessRenderer;
    if renderer().is_none() {
        return;
    }
    let model = InspectorModel::demo_sized(100_000);
    let size = (640, 400);
    let bg = [18u8, 18, 23];
    for cue in DepthCue::ALL {
        let shot = |r: Rasterizer| {
            let mut h = HeadlessRenderer::new(model.clone(), size).unwrap();
            h.app.ui_state.tab = Panel::View3d;
            let p = h.app.view3d_prefs_mut();
            (p.rasterizer, p.depth_cue, p.show_lines, p.show_frusta) = (r, cue, false, false);
            h.app.orbit_3d(25.0, 10.0);
            h.settled_frame().unwrap()
        };
        let (gl, cpu) = (shot(Rasterizer::Gl), shot(Rasterizer::Cpu));
        let drawn = gl
            .pixels()
            .filter(|p| (0..3).any(|k| (p.0[k] as i32 - bg[k] as i32).abs() > 3))
            .count();
        let differ = differing_pixels(&gl, &cpu, 8);
        eprintln!("{}: {differ} of {drawn} drawn pixels differ", cue.label());
        assert!(drawn > 20_000, "{}: only {drawn} pixels drawn", cue.label());
        assert!(
            differ * 100 <= drawn,
            "{}: CPU splatting differs from GL points in {differ} of {drawn} drawn pixels",
            cue.label()
        );
    }
}

/// CPU splatting: a still 300k-point view is complete in its first frame, and a re-fusion
/// that moves the pose draws the new pose complete at once (no preview frame).
#[test]
fn cpu_splatting_draws_a_still_view_complete_at_once() {
    if renderer().is_none() {
        return;
    }
    let (mut r, moved, complete) = moved_pose(300_000, (640, 400), Rasterizer::Cpu);
    r.app.set_model(moved);
    let first = r.frame(true).unwrap().unwrap();
    assert!(
        !r.app.view3d_refining(),
        "a still CPU-splatted view needed more than one frame"
    );
    assert_eq!(
        first.as_raw(),
        complete.as_raw(),
        "the first frame of the moved pose is not its complete view"
    );
}

/// The geometric branch's features are a control: picking SpinNet (KITTI checkpoint) sends the
/// pipeline's own parameters with `GeoFeatureSource::Spinnet` (the default export and keypoint
/// count, as `--geo-features spinnet-kitti`), and its keypoint count is then editable. A tall
/// window keeps every control of the side panel in view (no renderer needed: no snapshot).
#[test]
fn the_geometric_features_control_picks_spinnet() {
    use cgenreg::features::spinnet::Protocol;
    use cgenreg::pipeline::params::GeoFeatureSource;
    let seen = Arc::new(Mutex::new(Vec::new()));
    let handle = spawn_worker(Box::new(Recorder(seen.clone())), None);
    let mut app = App::new(InspectorModel::demo(), Some(handle), None);
    app.allow_dialogs = false;
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 3000.0))
        .with_pixels_per_point(1.0)
        .build_ui_state(|ui, app: &mut App| app.show(ui), app);
    h.run_steps(2);
    assert_eq!(h.state().params.geo_features, GeoFeatureSource::Fpfh);
    assert!(h
        .query_all_by_label("SpinNet keypoints per scan")
        .next()
        .is_none());
    h.get_by_label("Geometric features").click();
    h.run_steps(2);
    h.get_by_label("SpinNet (KITTI checkpoint)").click();
    h.run_steps(3);
    let want = GeoFeatureSource::spinnet(Protocol::Kitti);
    assert_eq!(h.state().params.geo_features, want);
    // the worker thread records the command when it gets it: wait for it (a loaded machine)
    let sent = || {
        seen.lock()
            .unwrap()
            .iter()
            .any(|c| matches!(c, Command::ApplySettings(p) if p.geo_features == want))
    };
    eventually(sent);
    assert!(sent(), "{:?}", seen.lock().unwrap());
    assert!(h
        .query_all_by_label("SpinNet keypoints per scan")
        .next()
        .is_some());
}

/// The correspondence lines follow the "line width" and "line opacity" controls: wider lines
/// cover more pixels of the inlier colour, fainter ones fewer.
#[test]
fn match_lines_follow_the_line_width_and_opacity_controls() {
    use cgenreg::app::colormap::INLIER_RGB;
    if renderer().is_none() {
        return;
    }
    let green = |width: f32, alpha: f32| {
        let mut app = demo_app();
        app.ui_state.tab = Panel::Views;
        app.ui_state.line_style.width = width;
        app.ui_state.line_style.alpha = alpha;
        let mut h = harness(app).unwrap();
        h.run_steps(4);
        assert!(h.query_all_by_label("line width").next().is_some());
        assert!(h.query_all_by_label("line opacity").next().is_some());
        count_near(&h.render().unwrap(), INLIER_RGB, 12)
    };
    let (thin, wide, faint) = (green(1.2, 1.0), green(4.0, 1.0), green(1.2, 0.2));
    eprintln!("inlier-coloured pixels: default {thin}, width 4 {wide}, opacity 0.2 {faint}");
    assert!(thin > 0, "no inlier line drawn");
    assert!(wide as f64 > 1.5 * thin as f64, "{wide} vs {thin}");
    assert!((faint as f64) < 0.5 * thin as f64, "{faint} vs {thin}");
}

/// A click at `pos` in the harness (press and release without moving).
fn click_at(h: &mut Harness<'static, App>, pos: egui::Pos2) {
    h.hover_at(pos);
    h.run_steps(1);
    h.drag_at(pos);
    h.run_steps(1);
    h.drop_at(pos);
    h.run_steps(2);
}

/// The distance tool: two clicks in the 3D view pick two points near where they were drawn,
/// and the distance is theirs in metres (two source points: the same under any pose); a
/// third click starts again; switching the tool off forgets the ends.
#[test]
fn the_distance_tool_measures_between_two_clicked_points() {
    use cgenreg::app::view3d::measure::{measurement, Cloud, Picked};
    let mut app = demo_app();
    app.ui_state.tab = Panel::View3d;
    let Some(mut h) = harness(app) else { return };
    h.run_steps(3);
    h.get_by_label("measure distance").click();
    h.run_steps(2);
    assert!(h.state().view3d().measure.active);
    let view = h.state().view3d();
    let inner = view.viewport().expect("a drawn 3D view").shrink(160.0);
    let on_screen = |i: usize| {
        view.screen_position(Picked {
            cloud: Cloud::Source,
            index: i,
        })
        .filter(|p| inner.contains(*p))
    };
    let n = h.state().model().source.len();
    let a = (0..n)
        .find_map(on_screen)
        .expect("a source point inside the view");
    let b = (0..n)
        .filter_map(on_screen)
        .find(|p| p.distance(a) > 80.0)
        .expect("a second source point apart from the first");
    click_at(&mut h, a);
    click_at(&mut h, b);
    let state = h.state();
    let picked = state.view3d().measure.picked.clone();
    assert_eq!(picked.len(), 2, "{picked:?}");
    for (p, clicked) in picked.iter().zip([a, b]) {
        assert_eq!(p.cloud, Cloud::Source);
        let drawn = state.view3d().screen_position(*p).unwrap();
        assert!(
            drawn.distance(clicked) <= 10.0,
            "{p:?} drawn at {drawn:?}, clicked {clicked:?}"
        );
    }
    let src = &state.model().source;
    let (pa, pb) = (src[picked[0].index], src[picked[1].index]);
    let want = (0..3)
        .map(|k| (pa[k] as f64 - pb[k] as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let pose = nalgebra::Isometry3::translation(1.0, 2.0, 3.0);
    let got = measurement(state.model(), &pose, &state.view3d().measure).unwrap();
    assert!(
        (got.distance_m - want).abs() < 1e-6,
        "{} vs {want}",
        got.distance_m
    );
    assert!(want > 0.0);
    h.remove_cursor();
    h.run_steps(2);
    h.snapshot("view3d-measure");
    click_at(&mut h, a);
    assert_eq!(h.state().view3d().measure.picked.len(), 1);
    h.get_by_label("measure distance").click();
    h.run_steps(2);
    assert!(h.state().view3d().measure.picked.is_empty());
    assert!(!h.state().view3d().measure.active);
}

/// "Apply prompt" sits below the fold of the side panel at 1280x800: scrolled to and clicked,
/// it applies the draft. With the image branch off it edits the kept prompt and re-runs
/// nothing; with it on, one settings command carries the new prompt. "Revert" drops a draft.
#[test]
fn apply_prompt_below_the_fold_applies_the_draft_and_revert_drops_it() {
    let Some((mut h, seen)) = recording_harness() else {
        return;
    };
    let minimal = PromptPreset::Minimal.default_scene();
    h.get_by_label("Minimal").click();
    h.run_steps(2);
    let apply = h.get_by_label("Apply prompt");
    let below = apply.rect().top() > 800.0;
    apply.scroll_to_me();
    // the scroll request is taken in the next pass and drawn in the one after
    h.run_steps(4);
    let apply = h.get_by_label("Apply prompt");
    assert!(below && apply.rect().bottom() < 800.0, "{:?}", apply.rect());
    h.get_by_label("Apply prompt").click();
    h.run_steps(3);
    assert_eq!(h.state().image_off.prompt.scene, minimal);
    assert!(h.query_all_by_label("Apply prompt").next().is_none());
    let applied = |seen: &Arc<Mutex<Vec<Command>>>| {
        seen.lock()
            .unwrap()
            .iter()
            .filter_map(|c| match c {
                Command::ApplySettings(p) => Some(p.clone()),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    assert!(
        applied(&seen).is_empty(),
        "image branch off: nothing re-runs"
    );

    // the image branch on: a draft re-runs nothing, applying it sends one settings command
    let on = h.state().image_off.clone();
    h.state_mut().params.image = Some(on);
    h.run_steps(2);
    seen.lock().unwrap().clear();
    h.get_by_label("General").click();
    h.run_steps(3);
    assert!(applied(&seen).is_empty(), "a draft re-ran the pipeline");
    h.get_by_label("Apply prompt").scroll_to_me();
    h.run_steps(4);
    h.get_by_label("Apply prompt").click();
    h.run_steps(3);
    let general = PromptPreset::General.default_scene();
    // the worker thread records a command when it gets it: wait for it (a loaded machine)
    eventually(|| !applied(&seen).is_empty());
    let sent = applied(&seen);
    assert_eq!(sent.len(), 1, "{sent:?}");
    assert_eq!(sent[0].image.as_ref().unwrap().prompt.scene, general);
    assert_eq!(
        h.state().params.image.as_ref().unwrap().prompt.scene,
        general
    );

    // Revert: the draft goes, the prompt stays
    h.get_by_label("Wrong").click();
    h.run_steps(2);
    h.get_by_label("Revert").scroll_to_me();
    h.run_steps(4);
    h.get_by_label("Revert").click();
    h.run_steps(3);
    assert!(h.query_all_by_label("Apply prompt").next().is_none());
    assert_eq!(
        h.state().params.image.as_ref().unwrap().prompt.scene,
        general
    );
    assert_eq!(applied(&seen).len(), 1);
}
