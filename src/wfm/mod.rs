//! (in progress)
pub mod depth_video;
pub mod video;
