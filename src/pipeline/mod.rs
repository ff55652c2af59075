//! The stage graph: each stage is a pure function of its inputs and parameters; results are
//! keyed by content so the GUI and `bench` re-run only what changed.
//!
//! Modules, leaves first: `params` (the parameter types), `result` (what a registration
//! returns, the stage timer), `memo` (what a caller keeps in memory between registrations), `geo` (the geometric branch), `tail` (the
//! in-memory tail: similarity to evaluation), `stages` (one file per cached stage),
//! `plan` (the stage graph: the ordered steps of a registration with their keys, and what a
//! change invalidates), `image_branch` (runs the image branch's steps), `register` (the entry
//! point, [`Registration`]: plan, then run; `scales` runs it at several voxels and keeps the
//! most visibility-consistent pose), then `pair_loop` (the one loop over many pairs: cancel,
//! panic guard, timing), `study` and `shard` (many pairs).

pub mod export;
pub mod geo;
pub mod hypotheses;
pub mod image_branch;
pub mod manifest_settings;
pub mod memo;
pub mod pair_loop;
pub mod params;
pub mod plan;
pub mod register;
pub mod result;
pub mod scales;
pub mod shard;
pub mod stages;
pub mod study;
pub mod tail;
pub mod union;
pub mod visibility;

pub use crate::vfm::VfmSpec;
pub use memo::Memo;
pub use params::{ImageBranchParams, RegisterParams, WfmSpec};
pub use plan::{plan, Plan, StageName, Step};
pub use register::Registration;
pub use result::{ImageBranchOutput, RegistrationResult, StageTiming, ViewInfo};
