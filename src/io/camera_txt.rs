//! Whitespace-separated matrix text files: camera intrinsics (3x3 K, or 4x4 whose top-left
//! 3x3 is K, as in ScanNet) and 4x4 poses (7-Scenes `frame-XXXXXX.pose.txt`: camera-to-world,
//! p_world = P * p_camera).

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::transform::isometry_from_matrix;
use nalgebra::{Isometry3, Matrix4};
use std::path::Path;

/// Read all numbers of a text file; comments after '#' are ignored.
pub fn read_numbers(path: &Path) -> Result<Vec<f64>> {
    let text = crate::io::limits::read_text(path)?;
    parse_numbers(path, &text)
}

pub fn parse_numbers(path: &Path, text: &str) -> Result<Vec<f64>> {
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for tok in line.split_whitespace() {
            let v: f64 = tok.parse().map_err(|_| {
                Error::format(
                    path,
                    format!("line {}", ln + 1),
                    "a number",
                    crate::io::output::unquoted(tok),
                )
            })?;
            if !v.is_finite() {
                return Err(Error::format(
                    path,
                    format!("line {}", ln + 1),
                    "a finite number",
                    tok,
                ));
            }
            out.push(v);
        }
    }
    Ok(out)
}

/// Read pinhole intrinsics for images of `width` x `height`.
pub fn read_intrinsics(path: &Path, width: u32, height: u32) -> Result<Intrinsics> {
    let text = crate::io::limits::read_text(path)?;
    parse_intrinsics(path, &text, width, height)
}

/// [`read_intrinsics`] on the file's text; `path` is used only in error messages.
pub fn parse_intrinsics(path: &Path, text: &str, width: u32, height: u32) -> Result<Intrinsics> {
    let v = parse_numbers(path, text)?;
    let (fx, fy, cx, cy) = match v.len() {
        9 => (v[0], v[4], v[2], v[5]),
        16 => (v[0], v[5], v[2], v[6]),
        n => {
            return Err(Error::format(
                path,
                "matrix",
                "9 numbers (3x3 K) or 16 numbers (4x4 with K top-left)",
                format!("{n} numbers"),
            ))
        }
    };
    if fx <= 0.0 || fy <= 0.0 {
        return Err(Error::format(
            path,
            "fx/fy",
            "positive focal lengths",
            format!("fx={fx} fy={fy}"),
        ));
    }
    Ok(Intrinsics {
        fx,
        fy,
        cx,
        cy,
        width,
        height,
    })
}

/// Read a 4x4 rigid transform. Which direction it is depends on the file (see the caller).
pub fn read_pose(path: &Path) -> Result<Isometry3<f64>> {
    let text = crate::io::limits::read_text(path)?;
    parse_pose(path, &text)
}

/// [`read_pose`] on the file's text; `path` is used only in error messages.
pub fn parse_pose(path: &Path, text: &str) -> Result<Isometry3<f64>> {
    let v = parse_numbers(path, text)?;
    if v.len() != 16 {
        return Err(Error::format(
            path,
            "matrix",
            "16 numbers (4x4 row-major)",
            format!("{} numbers", v.len()),
        ));
    }
    let m = Matrix4::from_row_slice(&v);
    isometry_from_matrix(&m).ok_or_else(|| {
        Error::format(
            path,
            "matrix",
            "a rigid transform (rotation + translation, last row 0 0 0 1)",
            "a non-rigid matrix",
        )
    })
}

/// Write a 4x4 matrix as text, row-major, one row per line.
pub fn write_pose(path: &Path, t: &Isometry3<f64>) -> Result<()> {
    let m = t.to_homogeneous();
    let mut s = String::new();
    for r in 0..4 {
        let row: Vec<String> = (0..4).map(|c| format!("{:.9e}", m[(r, c)])).collect();
        s.push_str(&row.join(" "));
        s.push('\n');
    }
    crate::error::write_atomic(path, s.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intrinsics_3x3_and_4x4() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("k.txt");
        std::fs::write(&p, "585 0 320\n0 585 240\n0 0 1\n").unwrap();
        let k = read_intrinsics(&p, 640, 480).unwrap();
        assert_eq!((k.fx, k.fy, k.cx, k.cy), (585.0, 585.0, 320.0, 240.0));
        std::fs::write(&p, "577.6 0 318.9 0\n0 578.7 242.7 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        let k = read_intrinsics(&p, 640, 480).unwrap();
        assert_eq!((k.fx, k.fy, k.cx, k.cy), (577.6, 578.7, 318.9, 242.7));
        std::fs::write(&p, "585 0 320\n0 585\n").unwrap();
        let e = read_intrinsics(&p, 640, 480).unwrap_err().to_string();
        assert!(e.contains("k.txt") && e.contains("5 numbers"), "{e}");
    }

    #[test]
    fn pose_rejects_garbage() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("pose.txt");
        std::fs::write(&p, "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        assert!(read_pose(&p).is_ok());
        std::fs::write(&p, "1 0 0 0\n0 1 0 0\n0 0 1 nan\n0 0 0 1\n").unwrap();
        assert!(read_pose(&p).unwrap_err().to_string().contains("finite"));
        std::fs::write(&p, "2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        assert!(read_pose(&p).unwrap_err().to_string().contains("rigid"));
    }
}
