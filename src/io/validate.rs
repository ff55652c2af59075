//! The checks every cloud reader makes of what it read: one validator, below the readers
//! (`cloud.rs` dispatches to the readers and so stands above them).

use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use std::path::Path;

/// Checks shared by every reader: at least one point, finite coordinates, and attribute
/// arrays as long as the point array.
pub fn validate_cloud(path: &Path, cloud: &PointCloud) -> Result<()> {
    if cloud.points.is_empty() {
        return Err(Error::format(
            path,
            "points",
            "at least one point",
            "an empty cloud",
        ));
    }
    if let Some(i) = cloud
        .points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
    {
        let p = cloud.points[i];
        return Err(Error::format(
            path,
            format!("point {i}"),
            "finite x, y, z",
            format!("({}, {}, {})", p.x, p.y, p.z),
        ));
    }
    let n = cloud.points.len();
    let check = |name: &str, len: Option<usize>| match len {
        Some(l) if l != n => Err(Error::format(
            path,
            name,
            format!("{n} entries (one per point)"),
            format!("{l}"),
        )),
        _ => Ok(()),
    };
    check("colors", cloud.colors.as_ref().map(Vec::len))?;
    check("normals", cloud.normals.as_ref().map(Vec::len))?;
    check("intensity", cloud.intensity.as_ref().map(Vec::len))?;
    Ok(())
}
