//! Support for this crate's own tests (unit and integration); not part of the API. (The fuzz
//! harness lives with the fuzz targets, in `fuzz/src/targets.rs`.)

pub mod rng;

pub use rng::Lcg;

use std::path::{Path, PathBuf};

fn ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

/// For tests on real data: the data root, or None to skip. When `CI=true` the data must be
/// there, so a missing root fails the test instead of silently skipping it.
#[allow(clippy::panic)] // a test's failure, by design
pub fn test_data_root() -> Option<PathBuf> {
    match super::data_root() {
        Some(p) => Some(p),
        None if ci() => {
            panic!(
                "CI=true but the real test data was not found at $CGENREG_DATA or ../shared/data"
            )
        }
        None => {
            eprintln!("skipping: real data not found (set CGENREG_DATA)");
            None
        }
    }
}

/// `root/rel` when that file exists, else None to skip; under `CI=true` a missing file
/// fails the test (a partial data folder must not pass by skipping).
#[allow(clippy::panic)] // a test's failure, by design
pub fn require_file(root: &Path, rel: &str) -> Option<PathBuf> {
    let p = root.join(rel);
    if p.exists() {
        return Some(p);
    }
    if ci() {
        panic!("CI=true but the test data file {} is missing", p.display());
    }
    eprintln!("skipping: {} missing", p.display());
    None
}
