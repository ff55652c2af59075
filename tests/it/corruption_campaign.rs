//! The corruption campaign: a real image-branch run on redkitchen (fragments rebuilt
//! from the raw RGB-D frames, built-in generator, XFeat), then, for one entry of every stage it
//! cached, each kind of damage to its payload and to its manifest. After every injection the
//! run must report the entry as corrupt, not use it (same pose and correspondences as the clean
//! run), recompute it, and leave a cache that verifies clean with no duplicate entries. A
//! cloud-only run of the same pair does the same for the `virtual-frames` stage.
//!
//! The table it prints (injected / reported / recomputed / used silently) is the one in
//! `docs/reliability.md`; `CGENREG_CAMPAIGN_TABLE=FILE` also writes it to FILE.
#![cfg(feature = "onnx")]

use crate::common;

use cgenreg::cache::Cache;
use cgenreg::dataset::fragment_cache::FragmentCacheStatus;
use cgenreg::dataset::Dataset;
use cgenreg::pipeline::{
    ImageBranchParams, RegisterParams, Registration, RegistrationResult, WfmSpec,
};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const MANIFEST: &str = "manifest.json";

#[derive(Clone, Copy, Debug)]
enum Damage {
    TruncatePayload,
    FlipPayload,
    DeletePayload,
    SwapPayload,
    TruncateManifest,
    EditManifestHash,
    DeleteManifest,
    SwapManifest,
}

const ALL: [Damage; 8] = [
    Damage::TruncatePayload,
    Damage::FlipPayload,
    Damage::DeletePayload,
    Damage::SwapPayload,
    Damage::TruncateManifest,
    Damage::EditManifestHash,
    Damage::DeleteManifest,
    Damage::SwapManifest,
];

impl Damage {
    fn label(self) -> &'static str {
        match self {
            Damage::TruncatePayload => "truncate payload",
            Damage::FlipPayload => "flip 16 payload bytes",
            Damage::DeletePayload => "delete payload",
            Damage::SwapPayload => "swap payload with a sibling entry",
            Damage::TruncateManifest => "truncate manifest",
            Damage::EditManifestHash => "edit one digit of a file hash in the manifest",
            Damage::DeleteManifest => "delete manifest",
            Damage::SwapManifest => "swap manifest with a sibling entry",
        }
    }
}

/// The largest payload file of an entry (the one whose damage matters most).
fn largest_payload(dir: &Path) -> PathBuf {
    let mut best: Option<(u64, PathBuf)> = None;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.file_name().unwrap() != MANIFEST {
                let n = std::fs::metadata(&p).unwrap().len();
                if best.as_ref().is_none_or(|(m, _)| n > *m) {
                    best = Some((n, p));
                }
            }
        }
    }
    best.expect("an entry has a payload").1
}

fn swap_files(a: &Path, b: &Path) {
    let (x, y) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
    assert_ne!(x, y, "swapping identical files would inject nothing");
    std::fs::write(a, y).unwrap();
    std::fs::write(b, x).unwrap();
}

/// Apply `d` to `entry`; `sibling` is another entry of the same stage (needed by the swaps).
/// Returns the entries that are now damaged, or None when the damage does not apply.
fn inject(d: Damage, entry: &Path, sibling: Option<&Path>) -> Option<Vec<PathBuf>> {
    let payload = largest_payload(entry);
    let manifest = entry.join(MANIFEST);
    match d {
        Damage::TruncatePayload => {
            let b = std::fs::read(&payload).unwrap();
            std::fs::write(&payload, &b[..b.len() / 2]).unwrap();
        }
        Damage::FlipPayload => {
            let mut b = std::fs::read(&payload).unwrap();
            let mid = b.len() / 2;
            let end = (mid + 16).min(b.len());
            for x in &mut b[mid..end] {
                *x ^= 0x5a;
            }
            std::fs::write(&payload, b).unwrap();
        }
        Damage::DeletePayload => std::fs::remove_file(&payload).unwrap(),
        Damage::SwapPayload => {
            let other = sibling?.join(payload.strip_prefix(entry).unwrap());
            if !other.exists() || std::fs::read(&other).ok()? == std::fs::read(&payload).ok()? {
                return None;
            }
            swap_files(&payload, &other);
            return Some(vec![entry.to_path_buf(), sibling?.to_path_buf()]);
        }
        Damage::TruncateManifest => {
            let b = std::fs::read(&manifest).unwrap();
            std::fs::write(&manifest, &b[..b.len() / 2]).unwrap();
        }
        Damage::EditManifestHash => {
            let text = std::fs::read_to_string(&manifest).unwrap();
            let at = text.find("\"blake3\"").expect("manifest lists file hashes");
            // The first digit of the value: the quote after the colon after the key.
            let colon = at + text[at..].find(':').unwrap();
            let digit = colon + text[colon..].find('"').unwrap() + 1;
            let mut b = text.into_bytes();
            b[digit] = if b[digit] == b'0' { b'1' } else { b'0' };
            std::fs::write(&manifest, b).unwrap();
        }
        Damage::DeleteManifest => std::fs::remove_file(&manifest).unwrap(),
        Damage::SwapManifest => {
            swap_files(&manifest, &sibling?.join(MANIFEST));
            return Some(vec![entry.to_path_buf(), sibling?.to_path_buf()]);
        }
    }
    Some(vec![entry.to_path_buf()])
}

/// `stage/0123456789ab`, as the warnings name an entry.
fn short(dir: &Path) -> String {
    let hash = dir.file_name().unwrap().to_string_lossy();
    let stage = dir.parent().unwrap().file_name().unwrap().to_string_lossy();
    format!("{stage}/{}", &hash[..12])
}

/// Every entry directory under the cache, by stage (sorted, so the campaign is reproducible).
fn entries(root: &Path) -> BTreeMap<String, Vec<PathBuf>> {
    let mut m: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();
    for s in std::fs::read_dir(root).unwrap() {
        let s = s.unwrap().path();
        if !s.is_dir() {
            continue;
        }
        let mut v: Vec<PathBuf> = std::fs::read_dir(&s)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_dir() && !p.file_name().unwrap().to_string_lossy().starts_with('.'))
            .collect();
        v.sort();
        if !v.is_empty() {
            m.insert(s.file_name().unwrap().to_string_lossy().into_owned(), v);
        }
    }
    m
}

fn counts(m: &BTreeMap<String, Vec<PathBuf>>) -> BTreeMap<String, usize> {
    m.iter().map(|(k, v)| (k.clone(), v.len())).collect()
}

struct Run {
    result: RegistrationResult,
    /// Pipeline warnings plus the fragment cache's rebuild messages.
    messages: Vec<String>,
}

fn run(ds: &Dataset, id: &str, cloud_only: bool, p: &RegisterParams, cache: &Cache) -> Run {
    let (mut pair, status) = ds.load_pair_status(id).unwrap();
    if cloud_only {
        pair.source.frames = None;
        pair.target.frames = None;
    }
    let result = Registration::new(p).cache(cache).run(&pair).unwrap();
    let mut messages = result.warnings.clone();
    for s in status.into_iter().flatten() {
        match s {
            FragmentCacheStatus::Rebuilt(why) | FragmentCacheStatus::NotStored(why) => {
                messages.push(why)
            }
            FragmentCacheStatus::Hit | FragmentCacheStatus::Built => {}
        }
    }
    Run { result, messages }
}

/// Same pose and correspondences: nothing from the damaged entry was used.
fn same_result(a: &RegistrationResult, b: &RegistrationResult) -> bool {
    common::pose_max_diff(&a.target_from_source, &b.target_from_source) < 1e-9
        && a.correspondences == b.correspondences
}

fn manifest_text(root: &Path, count: usize) -> String {
    format!(
        r#"name = "campaign"
root = "{}"

[fragment_options]
voxel = 0.01
max_depth = 4.0
crop = "3dmatch"

[[fragments]]
id = "0"
sequence = "7scenes-redkitchen-rgbd"
first = 0
count = {count}

[[fragments]]
id = "1"
sequence = "7scenes-redkitchen-rgbd"
first = 50
count = {count}

[[pairs]]
target = "0"
source = "1"
split = "3DMatch"
gt_log = "3dmatch-redkitchen/benchmark/3DMatch/gt.log"
"#,
        root.display()
    )
}

struct Row {
    stage: String,
    damage: Damage,
    injected: bool,
    reported: bool,
    recomputed: bool,
    silent: bool,
}

/// Damage one entry of each of `stages` in every way, re-run, and check.
fn campaign(
    ds: &Dataset,
    id: &str,
    cloud_only: bool,
    p: &RegisterParams,
    cache: &Cache,
    stages: Option<&[&str]>,
    rows: &mut Vec<Row>,
) {
    let clean = run(ds, id, cloud_only, p, cache);
    let again = run(ds, id, cloud_only, p, cache);
    assert!(same_result(&clean.result, &again.result));
    let before = entries(cache.root());
    assert!(cache.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
    for (stage, list) in &before {
        if stages.is_some_and(|s| !s.contains(&stage.as_str())) {
            continue;
        }
        for d in ALL {
            let entry = &list[0];
            let Some(damaged) = inject(d, entry, list.get(1).map(|p| p.as_path())) else {
                rows.push(Row {
                    stage: stage.clone(),
                    damage: d,
                    injected: false,
                    reported: false,
                    recomputed: false,
                    silent: false,
                });
                continue;
            };
            let r = run(ds, id, cloud_only, p, cache);
            let reported = damaged.iter().all(|e| {
                let name = short(e);
                r.messages.iter().any(|m| m.contains(&name))
            });
            let unused = same_result(&clean.result, &r.result);
            let verify = cache.verify_all().unwrap();
            let bad: Vec<_> = verify.iter().filter(|v| v.result.is_err()).collect();
            let after = entries(cache.root());
            let recomputed = bad.is_empty() && counts(&after) == counts(&before);
            eprintln!(
                "{stage:16} {:48} reported {reported} unused {unused} recomputed {recomputed}",
                d.label()
            );
            assert!(
                reported,
                "{stage}: {}: not reported; messages {:?}",
                d.label(),
                r.messages
            );
            assert!(unused, "{stage}: {}: the damaged entry was used", d.label());
            assert!(
                recomputed,
                "{stage}: {}: cache not clean after the run: bad {:?}, entries {:?} -> {:?}",
                d.label(),
                bad.iter()
                    .map(|v| v.result.clone().unwrap_err())
                    .collect::<Vec<_>>(),
                counts(&before),
                counts(&after)
            );
            rows.push(Row {
                stage: stage.clone(),
                damage: d,
                injected: true,
                reported,
                recomputed,
                silent: !unused,
            });
        }
    }
}

#[test]
fn every_damaged_stage_entry_is_reported_unused_and_recomputed() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let manifest = dir.path().join("campaign.toml");
    std::fs::write(&manifest, manifest_text(&root, 12)).unwrap();
    let cache_dir = dir.path().join("cache");
    let cache = Cache::open(&cache_dir).unwrap();
    let ds = Dataset::load(&manifest)
        .unwrap()
        .with_fragment_cache(Some(cache.clone()));
    let id = ds.pairs()[0].id.clone();
    // 10 cm keypoints (about a quarter of the 5 cm count) and fragments of 12 frames, L = 6:
    // every run after an injection recomputes the damaged stage and the tail, whose cost scales
    // with them, while what is tested (each damaged entry reported, unused and rewritten) does
    // not depend on them.
    let p = RegisterParams {
        voxel: 0.1,
        image: Some(ImageBranchParams {
            backend: WfmSpec::Builtin,
            frames_per_fragment: 6,
            margin: 1,
            k: 2,
            ..Default::default()
        }),
        ..Default::default()
    };
    let mut rows = Vec::new();
    // RGB-D fragments: every stage of the image-branch run, fragments included.
    campaign(&ds, &id, false, &p, &cache, None, &mut rows);
    // The same clouds without their frames: the virtual frames rendered for them.
    campaign(
        &ds,
        &id,
        true,
        &p,
        &cache,
        Some(&["virtual-frames"]),
        &mut rows,
    );

    let stages: std::collections::BTreeSet<_> = rows.iter().map(|r| r.stage.clone()).collect();
    for s in [
        "fragments",
        "geo-fpfh",
        // (no `depth-video`: the built-in generator draws each view from its own depth frame)
        "generation",
        "vfm-view",
        "lift",
        "image-points",
        "virtual-frames",
    ] {
        assert!(stages.contains(s), "campaign did not reach stage {s}");
    }
    let mut table = String::from(
        "| stage | damage | injected | reported | recomputed, cache clean | used silently |\n\
         |---|---|---:|---:|---:|---:|\n",
    );
    let yes = |b: bool| if b { "1" } else { "0" };
    for r in &rows {
        table += &format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            r.stage,
            r.damage.label(),
            yes(r.injected),
            yes(r.reported),
            yes(r.recomputed),
            yes(r.silent)
        );
    }
    let n = rows.iter().filter(|r| r.injected).count();
    let rep = rows.iter().filter(|r| r.reported).count();
    let silent = rows.iter().filter(|r| r.silent).count();
    table += &format!("\n{n} injected, {rep} reported, {silent} used silently\n");
    eprintln!("{table}");
    if let Some(f) = std::env::var_os("CGENREG_CAMPAIGN_TABLE") {
        std::fs::write(f, &table).unwrap();
    }
    assert_eq!(silent, 0);
    assert_eq!(rep, n);
}
