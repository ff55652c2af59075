//! cgenreg: training-free point-cloud registration by the C-GenReg method.
//!
//! Conventions used throughout the crate:
//! - Transforms are named by direction: `target_from_source: Isometry3<f64>` means
//!   `p_target = T * p_source`.
//! - Units are metres; camera axes follow OpenCV (x right, y down, z forward).
//! - Every artefact that leaves a stage carries its provenance (see `pipeline`).

pub mod camera;
pub mod cli;
pub mod dataset;
pub mod error;
pub mod estimate;
pub mod features;
pub mod fusion;
pub mod geometry;
pub mod io;
pub mod metrics;
pub mod pipeline;
pub mod synth;
pub mod vfm;
pub mod wfm;

#[cfg(feature = "gui")]
pub mod app;

pub use error::{Error, Result};
