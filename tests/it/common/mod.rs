//! Set-up shared by the integration tests that run the image branch on the bundled demo.
// Each test crate uses only part of this module.
#![allow(dead_code)]

use cgenreg::pipeline::{ImageBranchParams, RegisterParams, WfmSpec};
use std::path::PathBuf;

/// The bundled synthetic demo's manifest (made by this project; no download).
pub fn demo_manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml")
}

/// The full method on the demo with `backend`, for tests of its plumbing: the demo has 8
/// frames per sequence, so L = 8, m = 1 and K = 2 views ([0, 3] / [1, 4]); keypoints on a
/// 10 cm grid (about a quarter of the 5 cm count, a sixteenth of the similarity work: what these
/// tests check does not depend on it). The demo's accuracy is checked at 5 cm
/// ([`demo_params_5cm`]).
pub fn demo_params(backend: WfmSpec) -> RegisterParams {
    RegisterParams {
        voxel: 0.1,
        ..demo_params_5cm(backend)
    }
}

/// [`demo_params`] with the demo's own keypoint voxel (5 cm: the room is small and dense).
pub fn demo_params_5cm(backend: WfmSpec) -> RegisterParams {
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

/// The largest absolute difference between two 4x4 poses' entries (row-major `[[f64; 4]; 4]`).
pub fn pose_max_diff(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> f64 {
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
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

/// A stand-in for batch-mode Cosmos: one run for the whole JSONL; line i's depth video is
/// transcoded into `video_<i>/output.mp4`, and a prompt containing BLOCKED leaves an empty
/// `video_<i>/` as the guardrail does. Every run appends a line to `runs.log`.
/// The arguments after the program that the fake Cosmos scripts parse: the reference's
/// placeholders, substituted by the backend.
pub const FAKE_COSMOS_ARGS: [&str; 8] = [
    "--batch_input_path",
    "{batch_input_path}",
    "--video_save_folder",
    "{video_save_folder}",
    "--controlnet_specs",
    "{controlnet_specs}",
    "--seed",
    "{seed}",
];

pub fn fake_cosmos_batch(dir: &std::path::Path) -> PathBuf {
    let p = dir.join("fake_cosmos_batch.sh");
    std::fs::write(
        &p,
        format!(
            r#"#!/bin/sh
set -e
batch=""; out=""; seed=""
while [ $# -gt 0 ]; do
  case "$1" in
    --batch_input_path) batch="$2"; shift 2;;
    --video_save_folder) out="$2"; shift 2;;
    --controlnet_specs) shift 2;;
    --seed) seed="$2"; shift 2;;
    *) echo "unexpected argument: $1" >&2; exit 2;;
  esac
done
echo "seed $seed" >> "{runs}"
i=0
while IFS= read -r line; do
  video=$(printf '%s\n' "$line" | sed -n 's/.*"input_control": "\([^"]*\)".*/\1/p')
  prompt=$(printf '%s\n' "$line" | sed -n 's/^{{"prompt": "\([^"]*\)".*/\1/p')
  mkdir -p "$out/video_$i"
  case "$prompt" in
    *BLOCKED*) ;;
    *) ffmpeg -v error -y -i "$video" -vf scale=960:704 -c:v libx264 -pix_fmt yuv420p -crf 18 \
         "$out/video_$i/output.mp4" </dev/null
       printf '%s\n' "$prompt" > "$out/video_$i/prompt.txt";;
  esac
  i=$((i+1))
done < "$batch"
"#,
            runs = dir.join("runs.log").display()
        ),
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    p
}

/// The libtest name of test `name` in the module at `module_path` (`module_path!()`), for a
/// child process that re-runs one test of this binary with `--exact`: the path without the
/// crate's own name (`it::vfm_dense` -> `vfm_dense::name`).
pub fn test_name(module_path: &str, name: &str) -> String {
    match module_path.split_once("::") {
        Some((_, m)) => format!("{m}::{name}"),
        None => name.to_string(),
    }
}

/// Makes `$CGENREG_DATA` (which the bundled manifests expand) name `data`. The tests of this
/// binary run on parallel threads and `setenv` races with their `getenv`, so it is set at
/// most once, and not at all when it already names `data` (scripts/test.sh exports it).
pub fn export_data_env(data: &std::path::Path) {
    static ONCE: std::sync::Once = std::sync::Once::new();
    if std::env::var_os("CGENREG_DATA").as_deref() == Some(data.as_os_str()) {
        return;
    }
    ONCE.call_once(|| std::env::set_var("CGENREG_DATA", data));
}

/// Fraction of every 10th point of `query`, moved by `t`, with a `reference` point within `r`.
pub fn overlap(
    query: &[nalgebra::Point3<f32>],
    reference: &[nalgebra::Point3<f32>],
    t: &nalgebra::Isometry3<f64>,
    r: f32,
) -> f64 {
    let pts: Vec<[f32; 3]> = reference.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree = kiddo::ImmutableKdTree::new_from_slice(&pts).unwrap();
    let t = t.cast::<f32>();
    let sub: Vec<_> = query.iter().step_by(10).collect();
    let hits = sub
        .iter()
        .filter(|q| {
            let p = t * **q;
            tree.query(&[p.x, p.y, p.z])
                .nearest_one::<kiddo::SquaredEuclidean<f32>>()
                .execute()
                .distance
                <= r * r
        })
        .count();
    hits as f64 / sub.len() as f64
}

/// Oracle RGB + ALIKE-t with `mode` and every other option the default: the image branch of the
/// fusion study's rows (docs/ablation.md).
pub fn oracle_alike_params(mode: cgenreg::fusion::FusionMode) -> RegisterParams {
    RegisterParams {
        image: Some(ImageBranchParams {
            backend: WfmSpec::Oracle,
            vfm: cgenreg::pipeline::VfmSpec::Alike {
                model: cgenreg::vfm::default_model_path("alike-t.onnx"),
            },
            ..Default::default()
        }),
        fusion: cgenreg::fusion::FusionParams {
            mode,
            ..Default::default()
        },
        ..Default::default()
    }
}

/// `pair` registered again from kept `inputs` under `params` with `mode` (and `selection`, when
/// given): a branch alone or another fusion, from the same descriptors.
pub fn refuse_with(
    params: &RegisterParams,
    pair: &cgenreg::dataset::ScanPair,
    inputs: &cgenreg::pipeline::tail::FusionInputs,
    mode: cgenreg::fusion::FusionMode,
    selection: Option<cgenreg::fusion::Selection>,
) -> cgenreg::pipeline::RegistrationResult {
    let mut q = params.clone();
    q.fusion.mode = mode;
    if let Some(s) = selection {
        q.fusion.selection = s;
    }
    cgenreg::pipeline::Registration::new(&q)
        .refuse_from_memory(pair, inputs, None)
        .unwrap()
}

/// Asserts that `pose`'s share (F) is the largest of the visibility report's candidates: the
/// pose the rule keeps.
pub fn assert_largest_share(
    rep: &cgenreg::pipeline::visibility::VisibilityReport,
    pose: cgenreg::pipeline::visibility::Candidate,
) {
    let best = rep
        .candidates
        .iter()
        .map(|c| c.share)
        .fold(f64::MIN, f64::max);
    let kept = rep.candidates.iter().find(|c| c.pose == pose);
    assert_eq!(kept.map(|c| c.share), Some(best), "{:?}", rep.candidates);
}
