//! cgenreg's integration tests, one module per former test file, in one test binary.
//!
//! One binary links the library and its GUI / ONNX dependencies once instead of once per file:
//! on CI's 2-core machine that was most of the debug build (see docs/development.md).
//! Run one file's tests with `cargo test --test it <module>::`, e.g.
//! `cargo test --test it gui_snapshots::`. `tests/gui_monkey.rs` stays a binary of its own
//! because it changes the process's working directory.

// Tests: a failed step is the test failure.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

mod benchmark_layouts;
mod cache_safety;
mod corruption_campaign;
mod dataset_real;
mod docs_hygiene;
mod export_corr;
mod fusion_revisit;
mod fusion_share;
mod fusion_union;
mod fuzz_smoke;
mod geometry_cache;
mod gui_compare;
mod gui_pipeline;
mod gui_presets;
mod gui_run_all;
mod gui_settings;
mod gui_snapshots;
mod gui_structure;
mod gui_stuck;
mod gui_study;
mod gui_triage;
mod headless_no_egl;
mod headline;
mod hostile_outputs;
mod hostile_surfaces;
mod hypotheses;
mod io_limits;
mod io_malformed;
mod kitti07_lidar;
mod layering;
mod mast3r_export;
mod memory_bound;
mod pandaset_lidar;
mod pipeline_image;
mod properties;
mod score;
mod shard_cli;
mod slurm;
mod spinnet;
mod study;
mod validation;
mod vfm_dense;
mod vfm_onnx;
mod wfm_backends;
mod wfm_video;
