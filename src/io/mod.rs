//! Readers and writers, one file per format. Every reader states its conventions in its
//! module docs and returns `Error::Format` naming the file, the field and what was expected.

pub mod cloud;
pub mod color;
pub mod depth_png;
pub mod gtlog;
pub mod json_diff;
pub mod kitti;
pub mod limits;
pub mod lzf;
pub mod npy;
pub mod output;
pub mod pcd;
pub mod pickle;
pub mod ply;
pub mod validate;
pub mod xyz;
