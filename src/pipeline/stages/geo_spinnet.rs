//! Stage `geo-spinnet`: keypoints and SpinNet descriptors of one scan
//! ([`crate::features::spinnet`]). Key: the cloud's content hash; parameters: the keypoint
//! voxel, the point count, the protocol, the keypoint count, the seed of the keypoint and patch
//! draws, and the model (the export's content hash).

use super::{cloud_hash, points_flat, points_from, Ctx};
use crate::cache::{Cache, CacheKey, Entry};
use crate::dataset::Scan;
use crate::error::{Error, Result};
use crate::features::spinnet::{keypoints, Protocol};
use crate::geometry::PointCloud;
use crate::pipeline::inputs::GeoBranch;
use crate::pipeline::memo::Memo;
use serde_json::json;
use std::path::Path;

pub const STAGE: &str = "geo-spinnet";
pub const VERSION: u32 = 1;
/// Instead of `geo-fpfh`: the same stage of the graph.
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::Geo;
/// The seed of the keypoint subset and of the patch draws.
pub const SEED: u64 = 0;

/// What the stage reads besides the scan.
#[derive(Clone, Copy, Debug)]
pub struct SpinNetInput<'a> {
    pub protocol: Protocol,
    pub model: &'a Path,
    pub keypoints: usize,
    pub voxel: f64,
}

/// `spinnet-<protocol>@<first 16 hex digits of the export's blake3>`, the model's id in keys
/// and provenance.
pub fn model_id(memo: &Memo, input: &SpinNetInput) -> Result<String> {
    let h = memo.hash_file(input.model).map_err(|e| {
        Error::format(
            input.model,
            "model",
            format!(
                "a SpinNet ONNX export ({}; made by models/spinnet_export.sh)",
                input.protocol.onnx_file()
            ),
            e.to_string(),
        )
    })?;
    Ok(format!("spinnet-{}@{}", input.protocol.name(), &h[..16]))
}

pub fn key(scan: &Scan, input: &SpinNetInput, model_id: &str) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[&cloud_hash(&scan.cloud)],
        &json!({
            "voxel": input.voxel,
            "n_points": scan.cloud.len(),
            "protocol": input.protocol.name(),
            "keypoints": input.keypoints,
            "seed": SEED,
            "model": model_id,
        }),
    )
}

fn label(input: &SpinNetInput, model_id: &str) -> String {
    format!("{model_id}(n={}, v={:.3})", input.keypoints, input.voxel)
}

fn load(e: &Entry, label: String) -> Result<GeoBranch> {
    let (r, c, d) = e.read_f32_matrix("keypoints.npy")?;
    let points = points_from(r, c, &d, &e.path("keypoints.npy"))?;
    let features = e.read_features("spinnet.npy")?;
    if features.len() != points.len() {
        return Err(Error::Cache(format!(
            "{}: keypoints and features disagree in length",
            e.dir.display()
        )));
    }
    Ok(GeoBranch {
        keypoints: PointCloud::from_points(points),
        features,
        label,
    })
}

fn store(g: &GeoBranch, scan: &Scan, c: &Cache, k: &CacheKey) -> Result<()> {
    let mut ne = c.put(k, json!({ "scan": scan.name, "features": g.label }))?;
    ne.add_f32_matrix(
        "keypoints.npy",
        g.keypoints.len(),
        3,
        &points_flat(&g.keypoints.points),
    )?;
    ne.add_features("spinnet.npy", &g.features)?;
    ne.commit()?;
    Ok(())
}

/// Keypoints and descriptors of `scan`, computed here.
pub fn compute(scan: &Scan, input: &SpinNetInput, label: String) -> Result<GeoBranch> {
    if scan.cloud.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: cannot compute SpinNet descriptors of an empty cloud",
            scan.name
        )));
    }
    let kp = keypoints::select(&scan.cloud, input.voxel, input.keypoints, SEED);
    #[cfg(feature = "onnx")]
    {
        let net = crate::features::spinnet::model::SpinNet::load(input.model, input.protocol)?;
        let features = net.describe(&scan.cloud.points, &kp.points, SEED)?;
        Ok(GeoBranch {
            keypoints: kp,
            features,
            label,
        })
    }
    #[cfg(not(feature = "onnx"))]
    {
        let _ = (kp, label);
        Err(Error::Invalid(
            "SpinNet needs ONNX Runtime: this build has no `onnx` feature".into(),
        ))
    }
}

/// The scan's SpinNet branch through the cache, timed as `step`; with its key.
pub(crate) fn run(
    ctx: &mut Ctx,
    step: &str,
    scan: &Scan,
    input: &SpinNetInput,
) -> Result<(GeoBranch, CacheKey)> {
    let id = model_id(ctx.memo, input)?;
    let key = key(scan, input, &id)?;
    let lbl = label(input, &id);
    let g = ctx.stage(
        NAME,
        step,
        &key,
        |e| load(e, lbl.clone()),
        || compute(scan, input, lbl.clone()),
        |g, c, k| store(g, scan, c, k),
    )?;
    Ok((g, key))
}
