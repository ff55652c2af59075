//! Stage `geo-fpfh`: keypoints, normals and FPFH of one scan
//! ([`fpfh_branch`]). Key: the cloud's content hash; parameters: the
//! voxel size and the point count.

use super::{cloud_hash, points_flat, points_from, Ctx};
use crate::cache::{Cache, CacheKey, Entry};
use crate::dataset::Scan;
use crate::error::{Error, Result};
use crate::features::fpfh::{compute_fpfh, FpfhParams};
use crate::geometry::knn::KdIndex;
use crate::geometry::normals::{estimate_normals, orient_towards_viewpoint};
use crate::geometry::voxel::voxel_downsample;
use crate::geometry::PointCloud;
use crate::pipeline::graph::StageName;
use crate::pipeline::inputs::GeoBranch;
use crate::pipeline::params::RegisterParams;
use nalgebra::Point3;
use serde_json::json;

pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: StageName = StageName::Geo;

/// What the stage reads of the settings: the voxel size.
pub fn settings(p: &RegisterParams) -> f64 {
    let RegisterParams {
        voxel,
        // chooses this stage (FPFH) over SpinNet or features from files
        geo_features: _,
        fusion: _,
        estimator: _,
        inlier_threshold: _,
        image: _,
        success: _,
        // each scale hypothesis is a registration at one voxel
        scales: _,
    } = p;
    *voxel
}

pub fn key(scan: &Scan, voxel: f64) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[&cloud_hash(&scan.cloud)],
        &json!({ "voxel": voxel, "n_points": scan.cloud.len() }),
    )
}

fn load(e: &Entry, voxel: f64) -> Result<GeoBranch> {
    let (r, c, d) = e.read_f32_matrix("keypoints.npy")?;
    let points = points_from(r, c, &d, &e.path("keypoints.npy"))?;
    let (rn, cn, dn) = e.read_f32_matrix("normals.npy")?;
    let normals = points_from(rn, cn, &dn, &e.path("normals.npy"))?
        .into_iter()
        .map(|p| p.coords)
        .collect::<Vec<_>>();
    let features = e.read_features("fpfh.npy")?;
    if features.len() != points.len() || normals.len() != points.len() {
        return Err(Error::Cache(format!(
            "{}: keypoints, normals and features disagree in length",
            e.dir.display()
        )));
    }
    let mut kp = PointCloud::from_points(points);
    kp.normals = Some(normals);
    Ok(GeoBranch {
        keypoints: kp,
        features,
        label: format!("fpfh(v={voxel:.3})"),
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
    let normals: Vec<Point3<f32>> = g
        .keypoints
        .normals
        .as_ref()
        .map(|n| n.iter().map(|v| Point3::from(*v)).collect())
        .unwrap_or_default();
    ne.add_f32_matrix("normals.npy", normals.len(), 3, &points_flat(&normals))?;
    ne.add_features("fpfh.npy", &g.features)?;
    ne.commit()?;
    Ok(())
}

/// The scan's geometric branch through the cache, timed as `label`; with its key (the lift
/// stage chains it).
pub(crate) fn run(
    ctx: &mut Ctx,
    label: &str,
    scan: &Scan,
    voxel: f64,
) -> Result<(GeoBranch, CacheKey)> {
    let key = key(scan, voxel)?;
    let g = ctx.stage(
        NAME,
        label,
        &key,
        |e| load(e, voxel),
        || fpfh_branch(&scan.cloud, voxel),
        |g, c, k| store(g, scan, c, k),
    )?;
    Ok((g, key))
}

/// FPFH on the voxel-downsampled cloud: normals from local PCA (radius 2v, 30 neighbours)
/// oriented towards the scan origin (the first camera of a fragment), features radius 5v.
pub fn fpfh_branch(cloud: &PointCloud, voxel: f64) -> Result<GeoBranch> {
    if cloud.is_empty() {
        return Err(Error::Invalid(
            "cannot compute FPFH of an empty cloud".into(),
        ));
    }
    let mut kp = voxel_downsample(cloud, voxel);
    let index = KdIndex::new(&kp.points);
    let params = FpfhParams::for_voxel(voxel);
    let mut normals = estimate_normals(
        &kp.points,
        &index,
        params.normal_radius,
        params.normal_max_nn,
    );
    orient_towards_viewpoint(&kp.points, &mut normals, Point3::origin());
    let features = compute_fpfh(&kp.points, &normals, &index, &params);
    kp.normals = Some(normals);
    Ok(GeoBranch {
        keypoints: kp,
        features,
        label: format!("fpfh(v={voxel:.3})"),
    })
}
