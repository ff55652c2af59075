//! cgenreg: training-free point-cloud registration by the C-GenReg method.
//!
//! Conventions used throughout the crate:
//! - Transforms are named by direction: `target_from_source: Isometry3<f64>` means
//!   `p_target = T * p_source`.
//! - Units are metres; camera axes follow OpenCV (x right, y down, z forward).
//! - Every artefact that leaves a stage carries its provenance (see `pipeline`).

// Outside tests a failure is an `Error`, never a panic (`[lints]` in Cargo.toml denies
// unwrap/expect/panic); the unit tests may fail by panicking.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod cache;
pub mod camera;
pub mod cancel;
pub mod cli;
pub mod dataset;
pub mod error;
pub mod estimate;
pub mod features;
pub mod fusion;
pub mod geometry;
pub mod io;
pub mod matrix;
pub mod metrics;
pub mod onnx;
pub mod pipeline;
pub mod report;
pub mod simd;
pub mod synth;
pub mod vfm;
pub mod wfm;

#[cfg(feature = "gui")]
pub mod app;

pub use error::{Error, Result};

/// Where the staged real data lives: `$CGENREG_DATA`, else `<crate>/../shared/data`.
/// Returns None when neither exists.
pub fn data_root() -> Option<std::path::PathBuf> {
    if let Ok(p) = std::env::var("CGENREG_DATA") {
        let p = std::path::PathBuf::from(p);
        if p.is_dir() {
            return Some(p);
        }
    }
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    p.is_dir().then_some(p)
}

/// Support for this crate's own tests (unit and integration) and its fuzz targets; not part of
/// the API.
#[doc(hidden)]
pub mod testing;
