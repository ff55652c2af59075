//! The headline numbers, guarded through the CLI as a user runs them (skipped when the staged
//! data is missing, failing under CI=true): the staged 3DMatch/3DLoMatch pairs all register
//! geometry only, with the summary rows saying so; the first three redkitchen-rgbd pairs
//! register through the image branch (oracle frames, ALIKE-t). The demo pair's accuracy
//! against its exact ground truth is asserted in `pipeline_image::full_method_on_demo_with_cache`.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn manifest(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/manifests")
        .join(name)
}

/// `cgenreg bench <manifest> <args> --json`: the JSON and the printed table.
fn bench(data: &Path, manifest: &Path, args: &[&str]) -> (Value, String) {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("run.json");
    let o = Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .env_remove("CGENREG_CACHE")
        .env("CGENREG_DATA", data)
        .arg("bench")
        .arg(manifest)
        .args(args)
        .arg("--cache-dir")
        .arg(dir.path().join("cache"))
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "bench failed:\n{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    (
        serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap(),
        out,
    )
}

/// Every pair of the run a success (RRE ≤ 15°, RTE ≤ 30 cm), `n` of them in `split`, and the
/// split's summary row at 100 % recall, in the JSON and in the printed table.
fn all_registered(v: &Value, table: &str, split: &str, n: u64) {
    let rows: Vec<&Value> = v["pairs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["split"] == split)
        .collect();
    assert_eq!(rows.len() as u64, n, "{split}");
    for r in &rows {
        assert_eq!(r["success"], true, "{split}: {r}");
    }
    let s = v["summary"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["split"] == split)
        .unwrap_or_else(|| panic!("no {split} summary in {}", v["summary"]));
    assert_eq!(s["n"], n, "{s}");
    assert_eq!(s["recall"], 1.0, "{s}");
    let row = format!("| {split} | {n} | 100.0 |");
    assert!(table.contains(&row), "no {row:?} in\n{table}");
}

/// Staged redkitchen, geometry only (FPFH at 5 cm, SC2-PCR, the defaults): 12/12 3DMatch and
/// 4/4 3DLoMatch.
#[test]
fn staged_geometry_registers_all_16_pairs() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let (v, table) = bench(&data, &manifest("redkitchen-staged.toml"), &[]);
    assert_eq!(v["pairs"].as_array().unwrap().len(), 16);
    all_registered(&v, &table, "3DMatch", 12);
    all_registered(&v, &table, "3DLoMatch", 4);
}

/// redkitchen-rgbd 0-1, 0-2, 0-3 through the image branch: the real RGB frames (oracle),
/// ALIKE-t features, fused with FPFH (the default Noisy-AND): all three register.
#[test]
fn redkitchen_rgbd_image_branch_registers_three_pairs() {
    let Some(data) = cgenreg::testing::test_data_root() else {
        return;
    };
    let (v, table) = bench(
        &data,
        &manifest("redkitchen-rgbd.toml"),
        &["--limit", "3", "--wfm", "oracle", "--vfm", "alike"],
    );
    let rows = v["pairs"].as_array().unwrap();
    let ids: Vec<&str> = rows.iter().map(|r| r["id"].as_str().unwrap()).collect();
    assert_eq!(
        ids,
        [
            "redkitchen-rgbd/0-1",
            "redkitchen-rgbd/0-2",
            "redkitchen-rgbd/0-3"
        ]
    );
    all_registered(&v, &table, "3DMatch", 3);
    // the image branch ran with the frames and the model asked for
    let params = v["params"].to_string();
    assert!(
        params.contains("oracle") && params.to_lowercase().contains("alike"),
        "{params}"
    );
}
