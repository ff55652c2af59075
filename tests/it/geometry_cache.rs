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

/// One entry point for geometry alone: `Registration::run` with a cache writes one `geo-fpfh`
/// entry per scan and a second run loads both (the same pose); the inputs it keeps give,
/// through `refuse_from_memory` under the same parameters, the run's correspondences and pose
/// bit for bit.
#[test]
fn registration_caches_geometry_and_its_kept_inputs_refuse_to_the_same_result() {
    use cgenreg::cache::Cache;
    use cgenreg::dataset::Dataset;
    use cgenreg::pipeline::{RegisterParams, Registration};
    let ds = Dataset::load(&super::common::demo_manifest()).unwrap();
    let pair = ds.load_pair(&ds.pairs()[0].id.clone()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::open(dir.path()).unwrap();
    let p = RegisterParams::default();
    let status = |r: &cgenreg::pipeline::RegistrationResult| -> Vec<(String, String)> {
        r.timings
            .iter()
            .filter(|t| t.stage.starts_with("fpfh "))
            .map(|t| (t.stage.clone(), t.status.clone()))
            .collect()
    };
    let reg = Registration::new(&p).cache(&cache).keep(true);
    let mut first = reg.run(&pair).unwrap();
    let computed =
        |s: &str| [("fpfh source", s), ("fpfh target", s)].map(|(a, b)| (a.into(), b.into()));
    assert_eq!(status(&first), computed("computed"));
    assert_eq!(
        std::fs::read_dir(dir.path().join("geo-fpfh"))
            .unwrap()
            .count(),
        2
    );
    let second = Registration::new(&p).cache(&cache).run(&pair).unwrap();
    assert_eq!(status(&second), computed("cached"));
    assert!(second.inputs.is_none(), "nothing kept without `keep`");
    assert_eq!(second.target_from_source, first.target_from_source);
    let inputs = first.inputs.take().expect("kept with `keep`");
    assert!(inputs.image.is_none());
    let again = reg.refuse_from_memory(&pair, &inputs, None).unwrap();
    assert_eq!(again.correspondences, first.correspondences);
    assert_eq!(again.target_from_source, first.target_from_source);
    assert_eq!(again.n_inliers, first.n_inliers);
}
