//! Geometry alone goes through the same cached `geo-fpfh` stage as the image branch: a second
//! `bench --cache-dir` over the same pairs loads every FPFH from the cache and gives the same
//! poses.

use std::process::Command;

fn bench(manifest: &std::path::Path, cache: &std::path::Path, json: &std::path::Path) {
    let out = Command::new(env!("CARGO_BIN_EXE_cgenreg"))
        .env_remove("CGENREG_CACHE")
        .arg("bench")
        .arg(manifest)
        .arg("--cache-dir")
        .arg(cache)
        .arg("--json")
        .arg(json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "bench failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// (pair id, status of each FPFH stage, rre, rte) per record of a bench JSON.
fn fpfh_rows(json: &std::path::Path) -> Vec<(String, Vec<String>, f64, f64)> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
    v["records"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let st = r["stages"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|s| s["stage"].as_str().unwrap().starts_with("fpfh "))
                .map(|s| s["status"].as_str().unwrap().to_string())
                .collect();
            let res = &r["result"];
            (
                r["id"].as_str().unwrap().to_string(),
                st,
                res["rre_deg"].as_f64().unwrap(),
                res["rte_m"].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn a_second_geometry_only_bench_loads_fpfh_from_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let manifest = super::common::demo_manifest();
    let (a, b) = (dir.path().join("a.json"), dir.path().join("b.json"));
    bench(&manifest, &cache, &a);
    bench(&manifest, &cache, &b);
    let (first, second) = (fpfh_rows(&a), fpfh_rows(&b));
    assert!(!first.is_empty());
    assert_eq!(first.len(), second.len());
    for (f, s) in first.iter().zip(&second) {
        assert_eq!(f.0, s.0);
        assert_eq!(f.1, ["computed", "computed"], "{}: first run", f.0);
        assert_eq!(s.1, ["cached", "cached"], "{}: second run", s.0);
        // f32 features stored exactly: the same correspondences, the same pose
        assert_eq!(
            (f.2, f.3),
            (s.2, s.3),
            "{}: pose changed through the cache",
            f.0
        );
    }
    assert!(cache.join("geo-fpfh").is_dir());
}
