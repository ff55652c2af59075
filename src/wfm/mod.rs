//! The generated-RGB branch up to the generated frames: depth-video encoding as the reference
//! builds it, mp4 and PNG frame I/O, prompts, the frame split / view selection, and the world
//! foundation model (WFM) backends behind one trait.
//!
//! Backends (each labels its output with its true source in `Provenance::backend`):
//! - [`cosmos::CosmosBackend`]: runs a user-configured Cosmos-Transfer1 command on the batch
//!   files the reference writes, then ingests `video_0/output.mp4`;
//! - [`cached::CachedBackend`]: an existing Cosmos output folder plus its JSONL spec;
//! - [`oracle::OracleBackend`]: the dataset's real RGB frames ("C-GenReg (Oracle)");
//! - [`builtin::DepthShadeBackend`]: a deterministic shader of the depth video. NOT a WFM; it
//!   exists so the pipeline runs end to end without a GPU or a download.

pub mod backend;
pub mod builtin;
pub mod cached;
pub mod cosmos;
pub mod depth_video;
pub mod oracle;
pub mod prompt;
pub mod video;
pub mod views;

pub use backend::{GenerateRequest, Generation, Provenance, WfmBackend};
pub use prompt::{Prompt, PromptPreset};
pub use views::{select_views, ViewSelection};
