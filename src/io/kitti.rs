//! KITTI Velodyne `.bin` scans: consecutive little-endian f32 records, in the sensor frame
//! (metres, x forward, y left, z up). The KITTI layout is `x y z intensity` (16 bytes per
//! point); some tools write `x y z` only (12 bytes per point, no intensity).
//!
//! Which one a file is: what the user says (a manifest fragment's `kitti_fields = 3|4`, else
//! the environment variable `CGENREG_KITTI_FIELDS=3|4`), else the size when only one reading
//! fits it (a multiple of 16 but not 12: four fields; of 12 but not 16: three). A size that fits
//! both (a multiple of 48) keeps the KITTI layout when its fourth column reads as an intensity
//! (finite and not negative); otherwise the file is refused with an error that says how to
//! choose, rather than guessed.

use super::validate::validate_cloud;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use nalgebra::Point3;
use std::path::Path;

/// The environment variable that says how many f32 fields a `.bin` point has.
pub const FIELDS_ENV: &str = "CGENREG_KITTI_FIELDS";

/// Fields per point of a `.bin` scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KittiFields {
    /// `x y z` (12 bytes per point), no intensity.
    Xyz,
    /// `x y z intensity` (16 bytes per point), the KITTI layout.
    XyzIntensity,
}

impl KittiFields {
    /// 3 or 4; anything else is None.
    pub fn from_count(n: u64) -> Option<KittiFields> {
        match n {
            3 => Some(KittiFields::Xyz),
            4 => Some(KittiFields::XyzIntensity),
            _ => None,
        }
    }

    pub fn count(self) -> usize {
        match self {
            KittiFields::Xyz => 3,
            KittiFields::XyzIntensity => 4,
        }
    }

    /// `CGENREG_KITTI_FIELDS`, when set; a value other than 3 or 4 is an error naming it.
    pub fn from_env() -> Result<Option<KittiFields>> {
        match std::env::var(FIELDS_ENV) {
            Err(std::env::VarError::NotPresent) => Ok(None),
            Ok(v) => Self::from_env_value(&v),
            Err(e) => Err(Error::Param(format!(
                "environment variable {FIELDS_ENV}: {e}"
            ))),
        }
    }

    /// The value of `CGENREG_KITTI_FIELDS` ("" is unset).
    pub fn from_env_value(v: &str) -> Result<Option<KittiFields>> {
        if v.trim().is_empty() {
            return Ok(None);
        }
        v.trim()
            .parse::<u64>()
            .ok()
            .and_then(KittiFields::from_count)
            .map(Some)
            .ok_or_else(|| {
                Error::Param(format!(
                    "environment variable {FIELDS_ENV}: expected 3 (x, y, z) or 4 (x, y, z, intensity), found {v:?}"
                ))
            })
    }
}

/// Read a `.bin` scan; the layout follows `CGENREG_KITTI_FIELDS`, else the size (module docs).
pub fn read_kitti_bin(path: &Path) -> Result<PointCloud> {
    read_kitti_bin_fields(path, None)
}

/// Read a `.bin` scan with the layout `fields` when given, else as [`read_kitti_bin`].
pub fn read_kitti_bin_fields(path: &Path, fields: Option<KittiFields>) -> Result<PointCloud> {
    let fields = match fields {
        Some(f) => Some(f),
        None => KittiFields::from_env()?,
    };
    let bytes = crate::io::limits::read_file(path)?;
    parse_kitti_bin_fields(path, &bytes, fields)
}

/// Parse KITTI bytes by the size rule (no environment); `path` is used only in error messages.
pub fn parse_kitti_bin(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    parse_kitti_bin_fields(path, bytes, None)
}

const HOW: &str =
    "set kitti_fields = 3 or 4 on the manifest fragment, or CGENREG_KITTI_FIELDS=3 or 4";

/// Parse KITTI bytes with `fields` points, or by the size rule when None.
pub fn parse_kitti_bin_fields(
    path: &Path,
    bytes: &[u8],
    fields: Option<KittiFields>,
) -> Result<PointCloud> {
    let n = bytes.len();
    let f = |b: &[u8]| f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    let fields = match fields {
        Some(KittiFields::XyzIntensity) if !n.is_multiple_of(16) => {
            return Err(Error::format(
                path,
                "length",
                "a multiple of 16 bytes (x, y, z, intensity as f32, as you asked)",
                format!("{n} bytes ({} left over)", n % 16),
            ))
        }
        Some(KittiFields::Xyz) if !n.is_multiple_of(12) => {
            return Err(Error::format(
                path,
                "length",
                "a multiple of 12 bytes (x, y, z as f32, as you asked)",
                format!("{n} bytes ({} left over)", n % 12),
            ))
        }
        Some(k) => k,
        None => match (n.is_multiple_of(16), n.is_multiple_of(12)) {
            (true, false) => KittiFields::XyzIntensity,
            (false, true) => KittiFields::Xyz,
            (false, false) => {
                return Err(Error::format(
                    path,
                    "length",
                    "a multiple of 16 bytes (x, y, z, intensity as f32) or of 12 (x, y, z)",
                    format!("{n} bytes ({} left over for 16, {} for 12)", n % 16, n % 12),
                ))
            }
            (true, true) => {
                // Both readings fit the size: keep KITTI's unless its 4th column cannot be an
                // intensity.
                let bad = bytes
                    .chunks_exact(16)
                    .map(|r| f(&r[12..16]))
                    .enumerate()
                    .find(|(_, v)| !(v.is_finite() && *v >= 0.0));
                match bad {
                    None => KittiFields::XyzIntensity,
                    Some((i, v)) => {
                        return Err(Error::format(
                            path,
                            "fields per point",
                            format!("an unambiguous layout: {n} bytes fit both x, y, z, intensity (16-byte points) and x, y, z (12-byte points), and read as 16-byte points the intensity of point {i} is {v}, which no LiDAR gives; {HOW}"),
                            "neither said",
                        ))
                    }
                }
            }
        },
    };
    let step = fields.count() * 4;
    let mut points = Vec::with_capacity(n / step);
    let mut intensity = Vec::with_capacity(if step == 16 { n / step } else { 0 });
    for r in bytes.chunks_exact(step) {
        points.push(Point3::new(f(&r[0..4]), f(&r[4..8]), f(&r[8..12])));
        if step == 16 {
            intensity.push(f(&r[12..16]));
        }
    }
    let cloud = PointCloud {
        points,
        intensity: (step == 16).then_some(intensity),
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
    crate::io::output::write_atomic(path, &out)
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

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    #[test]
    fn three_float_files_by_size_and_by_request() {
        let p = Path::new("scan.bin");
        // 5 points of x, y, z: 60 bytes, a multiple of 12 but not of 16 -> the only reading.
        let xyz: Vec<f32> = (0..15).map(|i| i as f32 - 7.0).collect();
        let c = parse_kitti_bin(p, &f32s(&xyz)).unwrap();
        assert_eq!(c.len(), 5);
        assert!(c.intensity.is_none());
        assert_eq!(c.points[4], Point3::new(5.0, 6.0, 7.0));
        // 4 points of x, y, z, intensity: 64 bytes -> the KITTI reading.
        let xyzi: Vec<f32> = (0..16).map(|i| i as f32).collect();
        let c = parse_kitti_bin(p, &f32s(&xyzi)).unwrap();
        assert_eq!(c.len(), 4);
        assert_eq!(c.intensity.as_deref(), Some(&[3.0, 7.0, 11.0, 15.0][..]));
        // 12 points of x, y, z = 144 bytes = 9 KITTI points: both readings fit the size.
        // With a negative value in the would-be intensity column it is refused, with the way out.
        let amb: Vec<f32> = (0..36).map(|i| (i as f32 - 18.0) * 0.5).collect();
        let e = parse_kitti_bin(p, &f32s(&amb)).unwrap_err().to_string();
        assert!(
            e.contains("scan.bin")
                && e.contains("144 bytes")
                && e.contains("CGENREG_KITTI_FIELDS=3")
                && e.contains("kitti_fields"),
            "{e}"
        );
        // Said explicitly, each reading is taken.
        let c = parse_kitti_bin_fields(p, &f32s(&amb), Some(KittiFields::Xyz)).unwrap();
        assert_eq!(c.len(), 12);
        assert_eq!(c.points[1], Point3::new(-7.5, -7.0, -6.5));
        let four: Vec<f32> = (0..36).map(|i| i as f32).collect();
        let c = parse_kitti_bin(p, &f32s(&four)).unwrap();
        assert_eq!(
            c.len(),
            9,
            "a plausible intensity column keeps the KITTI layout"
        );
        let c = parse_kitti_bin_fields(p, &f32s(&four), Some(KittiFields::Xyz)).unwrap();
        assert_eq!(c.len(), 12);
        // A request the size contradicts is an error, not a silent other reading.
        let e = parse_kitti_bin_fields(p, &f32s(&xyz), Some(KittiFields::XyzIntensity))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("multiple of 16") && e.contains("as you asked"),
            "{e}"
        );
        let e = parse_kitti_bin_fields(p, &f32s(&xyzi[..14]), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("of 12"), "{e}");
    }

    #[test]
    fn fields_from_the_environment_value() {
        assert_eq!(
            KittiFields::from_env_value("3").unwrap(),
            Some(KittiFields::Xyz)
        );
        assert_eq!(
            KittiFields::from_env_value(" 4 ").unwrap(),
            Some(KittiFields::XyzIntensity)
        );
        assert_eq!(KittiFields::from_env_value("").unwrap(), None);
        let e = KittiFields::from_env_value("xyz").unwrap_err().to_string();
        assert!(
            e.contains("CGENREG_KITTI_FIELDS") && e.contains("\"xyz\""),
            "{e}"
        );
    }
}
