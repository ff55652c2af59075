//! KITTI Velodyne `.bin` scans: consecutive little-endian f32 records `x y z intensity`
//! (16 bytes per point), in the sensor frame (metres, x forward, y left, z up).

use super::cloud::validate_cloud;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use nalgebra::Point3;
use std::path::Path;

pub fn read_kitti_bin(path: &Path) -> Result<PointCloud> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_kitti_bin(path, &bytes)
}

/// Parse KITTI bytes; `path` is used only in error messages.
pub fn parse_kitti_bin(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    if !bytes.len().is_multiple_of(16) {
        return Err(Error::format(
            path,
            "length",
            "a multiple of 16 bytes (x, y, z, intensity as f32)",
            format!("{} bytes ({} left over)", bytes.len(), bytes.len() % 16),
        ));
    }
    let f = |b: &[u8]| f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    let n = bytes.len() / 16;
    let mut points = Vec::with_capacity(n);
    let mut intensity = Vec::with_capacity(n);
    for r in bytes.chunks_exact(16) {
        points.push(Point3::new(f(&r[0..4]), f(&r[4..8]), f(&r[8..12])));
        intensity.push(f(&r[12..16]));
    }
    let cloud = PointCloud {
        points,
        intensity: Some(intensity),
        ..Default::default()
    };
    validate_cloud(path, &cloud)?;
    Ok(cloud)
}

/// Write a KITTI `.bin` (intensity 0 when the cloud has none), atomically.
pub fn write_kitti_bin(path: &Path, cloud: &PointCloud) -> Result<()> {
    let mut out = Vec::with_capacity(cloud.len() * 16);
    for (i, p) in cloud.points.iter().enumerate() {
        let it = cloud
            .intensity
            .as_ref()
            .and_then(|v| v.get(i))
            .copied()
            .unwrap_or(0.0);
        for v in [p.x, p.y, p.z, it] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    crate::error::write_atomic(path, &out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.bin");
        let c = PointCloud {
            points: (0..5)
                .map(|i| Point3::new(i as f32, -2.0 * i as f32, 0.5))
                .collect(),
            intensity: Some(vec![0.1, 0.2, 0.3, 0.4, 0.5]),
            ..Default::default()
        };
        write_kitti_bin(&p, &c).unwrap();
        assert_eq!(read_kitti_bin(&p).unwrap(), c);
        let bytes = std::fs::read(&p).unwrap();
        let e = parse_kitti_bin(&p, &bytes[..70]).unwrap_err().to_string();
        assert!(e.contains("s.bin") && e.contains("multiple of 16"), "{e}");
        let e = parse_kitti_bin(&p, &[]).unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
        let mut bad = bytes.clone();
        bad[36..40].copy_from_slice(&f32::INFINITY.to_le_bytes());
        let e = parse_kitti_bin(&p, &bad).unwrap_err().to_string();
        assert!(e.contains("point 2"), "{e}");
    }
}
