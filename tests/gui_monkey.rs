//! GUI monkey test: thousands of seeded random events (clicks, drags, keys, typing, scrolls,
//! tab switches, bad files dropped) on the inspector with a real worker over the staged
//! 7-Scenes redkitchen pairs. Nothing may panic, no frame may block on the worker, and after
//! the storm the worker still answers: the current pair finishes (or fails with a message).
//!
//! Reproduce a failure with the seed it prints: `CGENREG_MONKEY_SEED=<seed> cargo test --test
//! gui_monkey`; `CGENREG_MONKEY_EVENTS` sets the number of events (default 5000).

// Tests: a failed step is the test failure.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#![cfg(feature = "gui")]

use cgenreg::app::channel::spawn_worker;
use cgenreg::app::model::PairStatus;
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{App, InspectorModel};
use cgenreg::pipeline::RegisterParams;
use eframe::egui;
use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The staged data, or None (skip) outside CI; under CI=true it must exist.
fn data_root() -> Option<PathBuf> {
    let p = std::env::var_os("CGENREG_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if p.join("3dmatch-redkitchen").is_dir() {
        return Some(p);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but the staged data is missing at {}", p.display());
    }
    eprintln!("skipping: no data at {}", p.display());
    None
}

/// splitmix64: small, seeded, reproducible.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

#[derive(Debug)]
struct Dropped(PathBuf);
impl egui::DroppedFile for Dropped {
    fn path(&self) -> &Path {
        &self.0
    }
    fn bytes(&self) -> Result<Vec<u8>, String> {
        std::fs::read(&self.0).map_err(|e| e.to_string())
    }
}

/// Prints the seed when the test fails (panics) anywhere below.
struct SeedOnPanic(u64);
impl Drop for SeedOnPanic {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!(
                "gui_monkey failed with seed {0}: reproduce with CGENREG_MONKEY_SEED={0}",
                self.0
            );
        }
    }
}

const KEYS: [egui::Key; 16] = [
    egui::Key::J,
    egui::Key::K,
    egui::Key::ArrowUp,
    egui::Key::ArrowDown,
    egui::Key::ArrowLeft,
    egui::Key::ArrowRight,
    egui::Key::Tab,
    egui::Key::Escape,
    egui::Key::Enter,
    egui::Key::Space,
    egui::Key::Backspace,
    egui::Key::R,
    egui::Key::Plus,
    egui::Key::Minus,
    egui::Key::Num1,
    egui::Key::Home,
];

const TABS: [&str; 8] = [
    "Pairs",
    "Views",
    "3D",
    "Posterior",
    "Plots",
    "Stages",
    "Compare",
    "Hypotheses",
];

#[test]
fn random_events_never_panic_block_or_wedge_the_worker() {
    let Some(data) = data_root() else { return };
    // The manifest expands $CGENREG_DATA.
    std::env::set_var("CGENREG_DATA", &data);
    let seed: u64 = std::env::var("CGENREG_MONKEY_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_261_201);
    let n_events: usize = std::env::var("CGENREG_MONKEY_EVENTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5000);
    let _guard = SeedOnPanic(seed);
    eprintln!("gui_monkey: seed {seed}, {n_events} events");

    let manifest =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-staged.toml");
    // The export and plot-saving buttons write relative paths (typed at random, too) into the
    // working directory: make it a scratch folder, never the checkout.
    let scratch = tempfile::tempdir().unwrap();
    std::env::set_current_dir(scratch.path()).unwrap();
    // Keypoints on a 10 cm grid: the storm re-runs pairs, and what is checked (no panic, no
    // blocked frame, a worker that still answers) does not depend on their number.
    let params = RegisterParams {
        voxel: 0.1,
        ..Default::default()
    };
    let mut worker = PipelineWorker::open_manifest(&manifest, params).unwrap();
    // A stage cache, as the inspector has by default: the storm switches pairs hundreds of
    // times over the same sixteen, and a user's inspector loads their FPFH from the cache then.
    let cache_dir = tempfile::tempdir().unwrap();
    worker.set_cache(Some(
        cgenreg::cache::Cache::open(cache_dir.path().join("cache")).unwrap(),
    ));
    let handle = spawn_worker(Box::new(worker), None);
    let mut app = App::new(InspectorModel::default(), Some(handle), None);
    app.allow_dialogs = false;
    let mut h = Harness::builder()
        .with_size(egui::vec2(1280.0, 800.0))
        .with_pixels_per_point(1.0)
        .build_ui_state(|ui, app: &mut App| app.show(ui), app);

    // Open the dataset as a user would (a dropped manifest) and let the first pair finish, so
    // that the events land on a populated inspector.
    h.input_mut()
        .dropped_files
        .push(Arc::new(Dropped(manifest.clone())));
    let t0 = Instant::now();
    while !h
        .state()
        .model()
        .current_pair
        .is_some_and(|c| matches!(h.state().model().pairs[c].status, PairStatus::Done))
    {
        h.step();
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the dataset never opened; log: {:?}",
            h.state().log.iter().map(|l| &l.text).collect::<Vec<_>>()
        );
        std::thread::sleep(Duration::from_millis(20));
    }

    // Bad files to drop: garbage PLY, a manifest that is not TOML, a missing path, a folder.
    let bad = tempfile::tempdir().unwrap();
    let garbage = bad.path().join("broken.ply");
    std::fs::write(
        &garbage,
        b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999\n",
    )
    .unwrap();
    let not_toml = bad.path().join("bad.toml");
    std::fs::write(&not_toml, b"[[pairs]\nsource = ").unwrap();
    let drops = [
        garbage,
        not_toml,
        bad.path().join("missing.pcd"),
        bad.path().to_path_buf(),
    ];

    let mut rng = Rng(seed);
    let (w, hgt) = (1280.0f32, 800.0f32);
    let pos = |rng: &mut Rng| egui::pos2(rng.unit() * w, rng.unit() * hgt);
    let mut slowest = Duration::ZERO;
    let mut dropped = 0usize;
    let started = Instant::now();
    for i in 0..n_events {
        match rng.below(20) {
            0..=6 => {
                let p = pos(&mut rng);
                h.hover_at(p);
                h.drag_at(p);
                h.drop_at(p);
            }
            7..=8 => {
                // A drag: sliders, the 3D orbit, plot pans.
                let a = pos(&mut rng);
                h.hover_at(a);
                h.drag_at(a);
                for _ in 0..3 {
                    h.hover_at(pos(&mut rng));
                }
                let b = pos(&mut rng);
                h.drop_at(b);
            }
            9..=11 => h.key_press(KEYS[rng.below(KEYS.len() as u64) as usize]),
            12 => h.event(egui::Event::Text(
                ["a", "0.5", "/tmp/", "é", " ", "-1", "1e308"][rng.below(7) as usize].into(),
            )),
            13 => {
                let p = pos(&mut rng);
                h.hover_at(p);
                h.event(egui::Event::MouseWheel {
                    unit: egui::MouseWheelUnit::Point,
                    delta: egui::vec2(0.0, (rng.unit() - 0.5) * 400.0),
                    phase: egui::TouchPhase::Move,
                    source: egui::MouseWheelSource::Unknown,
                    modifiers: egui::Modifiers::NONE,
                });
            }
            14..=16 => {
                let tab = TABS[rng.below(TABS.len() as u64) as usize];
                if let Some(n) = h.query_all_by_label(tab).next() {
                    n.click();
                }
            }
            17 => {
                // Switch pairs while the worker may be running.
                h.key_press(if rng.below(2) == 0 {
                    egui::Key::J
                } else {
                    egui::Key::K
                });
            }
            18 if rng.below(10) == 0 => {
                let f = &drops[rng.below(drops.len() as u64) as usize];
                h.input_mut()
                    .dropped_files
                    .push(Arc::new(Dropped(f.clone())));
                dropped += 1;
            }
            _ => h.key_press(egui::Key::Escape),
        }
        let t = Instant::now();
        h.step();
        let dt = t.elapsed();
        slowest = slowest.max(dt);
        // A frame that waits on the worker (a registration takes seconds) is a UI freeze;
        // even a debug build draws a frame in well under this.
        assert!(
            dt < Duration::from_secs(5),
            "event {i}: one frame took {dt:?} (the UI blocked)"
        );
    }
    eprintln!(
        "gui_monkey: {n_events} events ({dropped} bad files dropped) in {:.1} s, slowest frame {:?}",
        started.elapsed().as_secs_f64(),
        slowest
    );

    // The worker is not wedged: close whatever the monkey opened, open the dataset again and
    // see the worker answer ("opened ...") and finish the first pair, within a bound that
    // covers a debug-build registration queued behind whatever the monkey started. Finished
    // means registered, or refused with an input error: the storm types random settings (a
    // voxel that leaves a fragment two keypoints is a fair answer, "degenerate input"), and
    // which of them stick depends on what the worker had drawn when each click landed. A
    // panic caught in the worker is never a fair answer.
    for _ in 0..3 {
        h.key_press(egui::Key::Escape);
        h.step();
    }
    let log_len = h.state().log.len();
    h.input_mut()
        .dropped_files
        .push(Arc::new(Dropped(manifest.clone())));
    h.step();
    let t0 = Instant::now();
    loop {
        h.step();
        let st = h.state();
        let m = st.model();
        let answered = st.log[log_len.min(st.log.len())..]
            .iter()
            .any(|l| l.text.starts_with("opened "));
        let done = m.current_pair.is_some_and(|c| match &m.pairs[c].status {
            PairStatus::Done => true,
            PairStatus::Failed(why) => {
                assert!(!why.contains("panicked"), "the re-opened pair: {why}");
                true
            }
            PairStatus::Pending | PairStatus::Running => false,
        });
        if answered && done {
            eprintln!(
                "gui_monkey: worker answered the re-open {:.1} s after the last event ({:?})",
                t0.elapsed().as_secs_f64(),
                m.current_pair.map(|c| &m.pairs[c].status)
            );
            break;
        }
        if t0.elapsed() > Duration::from_secs(300) {
            panic!(
                "the worker never answered after the events: current pair {:?}, statuses {:?}, \
                 image branch {:?}; last log lines: {:?}",
                m.current_pair,
                m.pairs
                    .iter()
                    .map(|p| format!("{:?}", p.status))
                    .collect::<Vec<_>>(),
                st.params.image.as_ref().map(|i| (&i.backend, i.k)),
                st.log
                    .iter()
                    .rev()
                    .take(12)
                    .map(|l| &l.text)
                    .collect::<Vec<_>>()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
