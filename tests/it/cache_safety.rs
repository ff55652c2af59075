//! The cache commands that delete (`cache rm NAME`, `cache rm --all`, `cache verify
//! --remove-bad`) refuse a directory that is not a cgenreg cache (no marker file) and, in a
//! cache, remove only entry folders: a user's files next to the entries always survive.

use cgenreg::cache::{Cache, CacheKey, MARKER};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cgenreg"));
    c.env_remove("CGENREG_CACHE");
    c
}

fn cache_cmd(dir: &Path, args: &[&str]) -> Output {
    bin()
        .arg("cache")
        .arg("--dir")
        .arg(dir)
        .args(args)
        .output()
        .unwrap()
}

const HEX: &str = "0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";

/// A user's files: a thesis, photos, and a folder whose name looks like an entry's.
fn user_files(root: &Path) -> Vec<PathBuf> {
    let files = [
        root.join("docs/thesis/chapter1.tex"),
        root.join("docs/thesis/refs.bib"),
        root.join("photos/2024/img_0001.jpg"),
        root.join(format!("photos/{HEX}/img_0002.jpg")),
        root.join("notes.txt"),
    ];
    for f in &files {
        std::fs::create_dir_all(f.parent().unwrap()).unwrap();
        std::fs::write(f, b"precious").unwrap();
    }
    files.to_vec()
}

fn all_survive(files: &[PathBuf]) {
    for f in files {
        assert_eq!(
            std::fs::read(f).ok().as_deref(),
            Some(&b"precious"[..]),
            "{} was touched",
            f.display()
        );
    }
}

/// A real entry written through the library.
fn put_entry(c: &Cache, stage: &str, n: i64) -> CacheKey {
    let k = CacheKey::new(stage, 1, &["x"], &json!({ "n": n })).unwrap();
    let mut e = c.put(&k, json!({ "test": true })).unwrap();
    e.add_bytes("payload.bin", b"abc").unwrap();
    e.commit().unwrap();
    k
}

#[test]
fn commands_refuse_a_directory_without_the_marker() {
    let dir = tempfile::tempdir().unwrap();
    let files = user_files(dir.path());
    for args in [
        &["rm", "--all"][..],
        &["verify", "--remove-bad"],
        &["rm", "docs"],
        &["rm", "docs/thesis"],
        &["rm", "photos/2024"],
        &["rm", &format!("photos/{}", &HEX[..12])],
    ] {
        let o = cache_cmd(dir.path(), args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(
            err.contains("not a cgenreg cache") && err.contains(MARKER),
            "{args:?}: {err}"
        );
        all_survive(&files);
    }
    // Reading is allowed and changes nothing; no marker appears by itself.
    let o = cache_cmd(dir.path(), &["list"]);
    assert!(o.status.success());
    // `photos/<64 hex>` has an entry's name: listed (as a problem), not touched.
    assert!(String::from_utf8_lossy(&o.stdout).contains("1 entries"));
    assert!(!dir.path().join(MARKER).exists());
    all_survive(&files);
}

#[test]
fn a_marked_cache_loses_only_its_entries() {
    let dir = tempfile::tempdir().unwrap();
    let files = user_files(dir.path());
    // A cache made in a folder that is not empty is not marked by itself.
    let c = Cache::open(dir.path()).unwrap();
    assert!(!c.is_marked());
    let k1 = put_entry(&c, "lift", 1);
    let k2 = put_entry(&c, "lift", 2);
    let k3 = put_entry(&c, "photos", 3);
    let o = cache_cmd(dir.path(), &["init"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Three entries and the look-alike folder `photos/<64 hex>` (listed, it has an entry's name).
    assert!(String::from_utf8_lossy(&o.stdout).contains("marked"));
    assert!(c.is_marked());

    // Names that are not entries: refused or no-ops, never deleted.
    for args in [
        &["rm", "docs"][..],
        &["rm", "photos/2024"],
        &["rm", "docs/thesis"],
    ] {
        let _ = cache_cmd(dir.path(), args);
        all_survive(&files);
    }
    // A corrupt entry goes with --remove-bad; the user's files stay.
    let e = c.get(&k1).unwrap().unwrap();
    std::fs::write(e.path("payload.bin"), b"abd").unwrap();
    // `photos/<64 hex>` has an entry's name but no manifest: reported, never removed.
    let o = cache_cmd(dir.path(), &["verify", "--remove-bad"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(!o.status.success(), "{out}");
    assert!(out.contains("not removed") && out.contains(HEX), "{out}");
    assert!(c.get(&k1).unwrap().is_none());
    assert!(c.get(&k2).unwrap().is_some());
    all_survive(&files);
    // rm --all removes the entries, including the one in `photos/`, and nothing else.
    let o = cache_cmd(dir.path(), &["rm", "--all"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("removed 2 entries"));
    assert!(c.get(&k2).unwrap().is_none() && c.get(&k3).unwrap().is_none());
    all_survive(&files);
    assert!(dir.path().join(MARKER).is_file());
}

#[test]
fn a_new_cache_is_marked_and_library_removal_checks_it() {
    let dir = tempfile::tempdir().unwrap();
    let fresh = dir.path().join("fresh");
    let c = Cache::open(&fresh).unwrap();
    assert!(c.is_marked(), "a new cache gets the marker");
    put_entry(&c, "lift", 1);
    assert_eq!(c.remove_all().unwrap(), 1);

    let other = dir.path().join("other");
    let files = user_files(&other);
    let c = Cache::open(&other).unwrap();
    let k = put_entry(&c, "lift", 1);
    for r in [
        c.remove_all().map(|_| ()),
        c.remove_stage("lift").map(|_| ()),
        c.remove_entry("lift", &k.hash).map(|_| ()),
    ] {
        assert!(
            matches!(r, Err(cgenreg::Error::NotACache { ref dir, .. }) if dir == &other),
            "{r:?}"
        );
    }
    assert!(c.get(&k).unwrap().is_some());
    all_survive(&files);
}
