//! No stuck pair: after an error row the pair stays selected and every action the inspector
//! offers from it (Run the generator, Run geometry only, a settings change, another backend or
//! other geometric features) registers it. Each test drives one of the sequences a user met,
//! through the commands the side panel's buttons and controls send, to a result.
#![cfg(feature = "gui")]

use crate::common::{self, demo_manifest};

use std::path::Path;
use std::time::{Duration, Instant};

use cgenreg::app::model::{InspectorModel, PairStatus};
use cgenreg::app::worker::PipelineWorker;
use cgenreg::app::{paper_defaults, spawn_worker, Command, OpenKind, WorkerEvent, WorkerHandle};
use cgenreg::cache::Cache;
use cgenreg::dataset::manifest::Dataset;
use cgenreg::fusion::{FusionMode, Selection};
use cgenreg::pipeline::{RegisterParams, WfmSpec};

/// The next model whose current pair finished (done or failed), and the log lines on the way.
fn next_result(h: &WorkerHandle) -> (Box<InspectorModel>, Vec<String>) {
    let (t0, mut logs) = (Instant::now(), Vec::new());
    while t0.elapsed() < Duration::from_secs(300) {
        for e in h.poll() {
            match e {
                WorkerEvent::Log(_, t) => logs.push(t),
                WorkerEvent::Model(m) => {
                    let st = m.current_pair.map(|i| m.pairs[i].status.clone());
                    if matches!(st, Some(PairStatus::Done | PairStatus::Failed(_))) {
                        return (m, logs);
                    }
                }
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!("no result from the worker; log: {logs:?}");
}

fn status(m: &InspectorModel) -> (String, PairStatus) {
    let row = &m.pairs[m.current_pair.expect("a pair stays selected")];
    (row.id.clone(), row.status.clone())
}

fn assert_failed(m: &InspectorModel, id: &str, what: &str) -> String {
    match status(m) {
        (got, PairStatus::Failed(why)) if got == id => why,
        s => panic!("{what}: expected an error row of {id}, got {s:?}"),
    }
}

fn assert_done(m: &InspectorModel, id: &str, what: &str, logs: &[String]) {
    assert_eq!(
        status(m),
        (id.to_string(), PairStatus::Done),
        "{what}; log: {logs:?}"
    );
    assert!(m.estimated.is_some(), "{what}: a pose is shown");
}

/// "Run geometry only" as the side panel sends it: the branch off, geometry-only fusion and
/// selection.
fn geometry_only(p: &RegisterParams) -> RegisterParams {
    let mut g = p.clone();
    g.image = None;
    g.fusion.mode = FusionMode::default_for(false, false);
    g.fusion.selection = Selection::default_for(false);
    g
}

fn worker(manifest: &Path, params: RegisterParams, cache: &Path) -> (PipelineWorker, String) {
    let mut w = PipelineWorker::new(Dataset::load(manifest).unwrap(), params);
    w.set_cache(Some(Cache::open(cache).unwrap()));
    let id = w.pair_ids()[0].clone();
    (w, id)
}

/// The prompt loop on built-in frames: another prompt (not generated without asking) is an
/// error row saying no generation is cached; "Run the generator" registers the pair; a second
/// prompt and the generator again; then a temperature change re-fuses it.
#[test]
fn the_prompt_loop_on_built_in_frames_ends_in_a_result() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, id) = worker(
        &demo_manifest(),
        common::demo_params(WfmSpec::Builtin),
        tmp.path(),
    );
    let mut params = w.params().clone();
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::SelectPair(id.clone())));
    let (m, logs) = next_result(&h);
    assert_done(&m, &id, "first run", &logs);
    for prompt in ["a foggy warehouse at dawn", "a sunny kitchen, wooden floor"] {
        params.image.as_mut().unwrap().prompt.scene = prompt.to_string();
        assert!(h.send(Command::ApplySettings(params.clone())));
        let (m, _) = next_result(&h);
        assert_failed(&m, &id, "a new prompt");
        let missing = m
            .generation_missing
            .clone()
            .expect("the generator is offered");
        assert!(missing.contains(prompt), "{missing}");
        assert!(h.send(Command::RunGenerator { prompt: missing }));
        let (m, logs) = next_result(&h);
        assert!(
            !logs.iter().any(|l| l.contains("select a pair first")),
            "{logs:?}"
        );
        assert_done(&m, &id, "Run the generator", &logs);
    }
    params.fusion.calibration_img = params.fusion.calibration_img.with_tau(0.05);
    assert!(h.send(Command::ApplySettings(params)));
    let (m, logs) = next_result(&h);
    assert_done(&m, &id, "a temperature after the loop", &logs);
}

/// Two loose clouds: switching the image branch on is an error row (a generation is not made
/// without asking); "Run the generator" registers them with built-in frames of the clouds'
/// virtual views.
#[test]
fn the_first_switch_to_the_image_branch_on_two_loose_clouds_ends_in_a_result() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = Dataset::load(&demo_manifest()).unwrap();
    let tgt = ds.pairs()[0].target.clone();
    let target = ds.load_fragment(&tgt).unwrap().cloud;
    let mut source = target.clone();
    let t = nalgebra::Isometry3::new(
        nalgebra::Vector3::new(0.2, -0.1, 0.1),
        nalgebra::Vector3::new(0.05, 0.3, 0.0),
    )
    .inverse()
    .cast::<f32>();
    for p in source.points.iter_mut() {
        *p = t * *p;
    }
    source.normals = None;
    let dir = tmp.path().join("clouds");
    std::fs::create_dir(&dir).unwrap();
    cgenreg::io::cloud::save_cloud(&dir.join("tgt.ply"), &target).unwrap();
    cgenreg::io::cloud::save_cloud(&dir.join("src.ply"), &source).unwrap();
    let mut geo = paper_defaults();
    geo.voxel = 0.1;
    let (w, _) = worker(&demo_manifest(), geo.clone(), &tmp.path().join("cache"));
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::Open {
        kind: OpenKind::TwoClouds,
        paths: vec![dir.join("src.ply"), dir.join("tgt.ply")],
    }));
    let (m, logs) = next_result(&h);
    let id = status(&m).0;
    assert_done(&m, &id, "the clouds, geometry only", &logs);
    // the WFM control set to built-in frames (what the controls send)
    let mut img = common::demo_params(WfmSpec::Builtin);
    img.voxel = geo.voxel;
    img.fusion.mode = FusionMode::default_for(true, false);
    img.fusion.selection = Selection::default_for(true);
    assert!(h.send(Command::ApplySettings(img)));
    let (m, logs) = next_result(&h);
    if let (_, PairStatus::Failed(_)) = status(&m) {
        let missing = m
            .generation_missing
            .clone()
            .unwrap_or_else(|| panic!("an error row offers the generator: {logs:?}"));
        assert!(h.send(Command::RunGenerator { prompt: missing }));
        let (m, logs) = next_result(&h);
        assert_done(&m, &id, "Run the generator on the clouds", &logs);
    } else {
        assert_done(&m, &id, "the image branch on the clouds", &logs);
    }
}

/// Oracle frames on a LiDAR scan (no colour) are an error row; "Run geometry only" registers
/// it; back to oracle (the error again), then another backend (built-in frames) and the
/// generator register it.
#[test]
fn oracle_on_a_scan_without_colour_then_geometry_or_another_backend_ends_in_a_result() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    common::export_data_env(&root);
    let tmp = tempfile::tempdir().unwrap();
    let lidar =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/small-gicp-lidar.toml");
    let mut oracle = common::demo_params(WfmSpec::Oracle);
    (oracle.voxel, oracle.image.as_mut().unwrap().k) = (0.5, 1);
    let (w, id) = worker(&lidar, oracle.clone(), tmp.path());
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::SelectPair(id.clone())));
    let (m, _) = next_result(&h);
    let why = assert_failed(&m, &id, "oracle on LiDAR");
    assert!(why.contains("oracle"), "{why}");
    assert!(h.send(Command::ApplySettings(geometry_only(&oracle))));
    let (m, logs) = next_result(&h);
    assert!(
        !logs.iter().any(|l| l.contains("no pair selected")),
        "{logs:?}"
    );
    assert_done(&m, &id, "Run geometry only", &logs);
    assert!(h.send(Command::ApplySettings(oracle.clone())));
    let (m, _) = next_result(&h);
    assert_failed(&m, &id, "oracle again");
    let mut builtin = oracle.clone();
    builtin.image.as_mut().unwrap().backend = WfmSpec::Builtin;
    assert!(h.send(Command::ApplySettings(builtin.clone())));
    let (m, logs) = next_result(&h);
    if let (_, PairStatus::Failed(_)) = status(&m) {
        let p = builtin.image.as_ref().unwrap().prompt.text();
        assert!(h.send(Command::RunGenerator { prompt: p }));
        let (m, logs) = next_result(&h);
        assert_done(&m, &id, "built-in frames after oracle", &logs);
    } else {
        assert_done(&m, &id, "built-in frames after oracle", &logs);
    }
}

/// SpinNet without its ONNX export is an error row naming the file; choosing FPFH (a settings
/// change from the error row) registers the pair.
#[test]
fn spinnet_without_an_export_then_fpfh_ends_in_a_result() {
    let tmp = tempfile::tempdir().unwrap();
    let mut geo = paper_defaults();
    geo.voxel = 0.1;
    let mut spin = geo.clone();
    spin.geo_features = cgenreg::pipeline::params::GeoFeatureSource::Spinnet {
        protocol: cgenreg::features::spinnet::Protocol::ThreeDMatch,
        model: tmp.path().join("no-export/spinnet-3dmatch.onnx"),
        keypoints: 64,
    };
    let (w, id) = worker(&demo_manifest(), spin, &tmp.path().join("cache"));
    let h = spawn_worker(Box::new(w), None);
    assert!(h.send(Command::SelectPair(id.clone())));
    let (m, _) = next_result(&h);
    let why = assert_failed(&m, &id, "SpinNet without an export");
    assert!(why.contains("spinnet-3dmatch.onnx"), "{why}");
    assert!(h.send(Command::ApplySettings(geo)));
    let (m, logs) = next_result(&h);
    assert_done(&m, &id, "FPFH after SpinNet", &logs);
}
