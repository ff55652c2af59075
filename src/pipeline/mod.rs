//! The stage graph: each stage is a pure function of its inputs and parameters; results are
//! keyed by content so the GUI and `bench` re-run only what changed.

pub mod cache;
pub mod params;
pub mod register;

pub use params::RegisterParams;
pub use register::{register_pair, ImageBranchOutput, RegistrationResult, StageTiming, ViewInfo};
