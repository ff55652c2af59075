//! The stage graph: each stage is a pure function of its inputs and parameters; results are
//! keyed by content so the GUI and `bench` re-run only what changed.

pub mod cache;
pub mod image_branch;
pub mod params;
pub mod register;
pub mod shard;
pub mod study;

pub use params::{ImageBranchParams, RegisterParams, VfmSpec, WfmSpec};
pub use register::{
    register_pair, register_pair_cached, ImageBranchOutput, RegistrationResult, StageTiming,
    ViewInfo,
};
