//! The stage graph: each stage is a pure function of its inputs and parameters; results are
//! keyed by content so the GUI and `bench` re-run only what changed.
//!
//! Modules, leaves first (no import cycle, `tests/it/layering.rs`): `params` (the parameter
//! types), `graph` (the stage names, a plan's steps and which stages a registration has),
//! `memo` (what a caller keeps in memory between registrations), `inputs` (what the tail
//! computes from) and `arbitration` (what the arbitration modes report), `result` (what a
//! registration returns, the stage timer), `stages` (one file per cached stage), `geo` (the
//! geometric branch), `tail` (the in-memory tail: similarity to evaluation, the fusion modes
//! under it), `plan` (every key known before a run, and what a change invalidates),
//! `registration` (what one registration uses), `image_branch` and `run` (the single run: the
//! plan's steps in order), `scales` (the scale search above it), `register` (the entry point,
//! [`Registration::run`]), then `pair_loop` (the one loop over many pairs: cancel, panic
//! guard, timing), `study` and `shard` (many pairs).

pub mod arbitration;
pub mod export;
pub mod geo;
pub mod graph;
pub mod hypotheses;
pub mod image_branch;
pub mod inputs;
pub mod manifest_settings;
pub mod memo;
pub mod pair_loop;
pub mod params;
pub mod plan;
pub mod register;
pub mod registration;
pub mod result;
pub mod run;
pub mod scales;
pub mod shard;
pub mod stages;
pub mod study;
pub mod tail;

pub use crate::vfm::VfmSpec;
pub use graph::{Plan, StageName, Step};
pub use memo::Memo;
pub use params::{ImageBranchParams, RegisterParams, WfmSpec};
pub use plan::plan;
pub use register::Registration;
pub use result::{ImageBranchOutput, RegistrationResult, StageTiming, ViewInfo};
pub use tail::{union, visibility};
