//! Set-up shared by the integration tests that run the image branch on the bundled demo.
// Each test crate uses only part of this module.
#![allow(dead_code)]

use cgenreg::pipeline::{ImageBranchParams, RegisterParams, WfmSpec};
use std::path::PathBuf;

/// The bundled synthetic demo's manifest (made by this project; no download).
pub fn demo_manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml")
}

/// The full method on the demo with `backend`: the demo room is small and dense (keypoint
/// voxel 5 cm) and has 8 frames per sequence, so L = 8, m = 1 and K = 2 views
/// ([0, 3] / [1, 4]).
pub fn demo_params(backend: WfmSpec) -> RegisterParams {
    RegisterParams {
        voxel: 0.05,
        image: Some(ImageBranchParams {
            backend,
            frames_per_fragment: 8,
            margin: 1,
            k: 2,
            ..Default::default()
        }),
        ..Default::default()
    }
}
