//! TEMPORARY: replaced by the io helper's implementation at merge.
//!
//! Minimal `load_cloud` for the dataset helper's tests: binary little-endian PLY with float32
//! `x y z` (extra float32 vertex properties are skipped). Everything else is an error.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use nalgebra::Point3;
use std::path::Path;

// TEMPORARY: replaced by the io helper's implementation at merge
pub fn load_cloud(path: &Path) -> Result<PointCloud> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| {
            Error::format(path, "header", "a PLY header ending in end_header", "none")
        })?;
    let header = std::str::from_utf8(&bytes[..end])
        .map_err(|_| Error::format(path, "header", "ASCII text", "non-UTF-8 bytes"))?;
    if !header.starts_with("ply") || !header.contains("format binary_little_endian 1.0") {
        return Err(Error::format(
            path,
            "format",
            "binary_little_endian PLY (temporary reader)",
            "something else",
        ));
    }
    let mut n = None;
    let mut props = Vec::new();
    let mut in_vertex = false;
    for line in header.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["element", "vertex", c] => {
                n = c.parse::<usize>().ok();
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", "float", name] | ["property", "float32", name] if in_vertex => {
                props.push(name.to_string())
            }
            ["property", ..] if in_vertex => {
                return Err(Error::format(
                    path,
                    "vertex property",
                    "float32 (temporary reader)",
                    line,
                ))
            }
            _ => {}
        }
    }
    let n = n.ok_or_else(|| Error::format(path, "element vertex", "a vertex count", "none"))?;
    let idx = |name: &str| props.iter().position(|p| p == name);
    let (Some(ix), Some(iy), Some(iz)) = (idx("x"), idx("y"), idx("z")) else {
        return Err(Error::format(path, "properties", "x y z", props.join(" ")));
    };
    let stride = props.len() * 4;
    let body = &bytes[end + 11..];
    if body.len() < n * stride {
        return Err(Error::format(
            path,
            "vertex data",
            format!("{} bytes", n * stride),
            format!("{} bytes (truncated)", body.len()),
        ));
    }
    let f = |rec: &[u8], k: usize| {
        f32::from_le_bytes([rec[4 * k], rec[4 * k + 1], rec[4 * k + 2], rec[4 * k + 3]])
    };
    let mut pts = Vec::with_capacity(n);
    for (i, rec) in body.chunks_exact(stride).take(n).enumerate() {
        let p = Point3::new(f(rec, ix), f(rec, iy), f(rec, iz));
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return Err(Error::format(
                path,
                format!("vertex {i}"),
                "finite coordinates",
                format!("{p:?}"),
            ));
        }
        pts.push(p);
    }
    Ok(PointCloud::from_points(pts))
}
