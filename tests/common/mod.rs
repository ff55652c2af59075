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

/// JSON equality where numbers may differ by a relative 1e-12: the pipeline's parallel
/// reductions were once seen to move an RRE by 1 ulp between two runs of the same pair
/// under heavy load (the same binary, the same inputs), so bit-for-bit equality of two
/// separate runs is not guaranteed.
pub fn json_close(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (
                x.as_f64().unwrap_or(f64::NAN),
                y.as_f64().unwrap_or(f64::NAN),
            );
            x == y || (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1.0)
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| json_close(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| json_close(v, w)))
        }
        _ => a == b,
    }
}
