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

/// The numbers of a matrix file, one row per non-empty line (comments after '#' dropped),
/// refused unless it is `n` rows of `n` numbers for one of the sizes in `sizes`.
fn parse_square(path: &Path, text: &str, sizes: &[usize], what: &str) -> Result<Vec<Vec<f64>>> {
    let mut rows = Vec::new();
    for line in text.lines() {
        let row = parse_numbers(path, line.split('#').next().unwrap_or(""))?;
        if !row.is_empty() {
            rows.push(row);
        }
    }
    let n = rows.len();
    if !sizes.contains(&n) || rows.iter().any(|r| r.len() != n) {
        let lens: Vec<String> = rows.iter().map(|r| r.len().to_string()).collect();
        return Err(Error::format(
            path,
            "matrix",
            what,
            format!("{n} rows of {} numbers", lens.join(", ")),
        ));
    }
    Ok(rows)
}

/// [`read_intrinsics`] on the file's text; `path` is used only in error messages.
///
/// K must be `fx 0 cx / 0 fy cy / 0 0 1` with positive focal lengths and the principal point
/// inside the `width` x `height` image; a 4x4 must hold such a K top-left and otherwise be the
/// identity (ScanNet's layout). Anything else would back-project every depth pixel wrongly.
pub fn parse_intrinsics(path: &Path, text: &str, width: u32, height: u32) -> Result<Intrinsics> {
    let m = parse_square(
        path,
        text,
        &[3, 4],
        "3 rows of 3 numbers (K) or 4 rows of 4 (K top-left)",
    )?;
    let mut want: Vec<(usize, usize, f64)> = vec![
        (1, 0, 0.0),
        (0, 1, 0.0),
        (2, 0, 0.0),
        (2, 1, 0.0),
        (2, 2, 1.0),
    ];
    if m.len() == 4 {
        want.extend([
            (0, 3, 0.0),
            (1, 3, 0.0),
            (2, 3, 0.0),
            (3, 0, 0.0),
            (3, 1, 0.0),
            (3, 2, 0.0),
            (3, 3, 1.0),
        ]);
    }
    for (r, c, v) in want {
        if (m[r][c] - v).abs() > 1e-9 {
            let why = match (r, c) {
                (0, 1) => "0 (no skew)",
                (2, _) => "the last row of K to be 0 0 1",
                (_, 3) | (3, _) => "the identity outside K in a 4x4",
                _ => "0 (K is upper triangular)",
            };
            return Err(Error::format(
                path,
                format!("K[{r}][{c}]"),
                format!("{v} ({why})"),
                format!("{}", m[r][c]),
            ));
        }
    }
    let (fx, fy, cx, cy) = (m[0][0], m[1][1], m[0][2], m[1][2]);
    if fx <= 0.0 || fy <= 0.0 {
        return Err(Error::format(
            path,
            "fx/fy",
            "positive focal lengths",
            format!("fx={fx} fy={fy}"),
        ));
    }
    if !(cx > 0.0 && cx < width as f64 && cy > 0.0 && cy < height as f64) {
        return Err(Error::format(
            path,
            "cx/cy",
            format!("a principal point inside the {width}x{height} image"),
            format!("cx={cx} cy={cy}"),
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
    let rows = parse_square(
        path,
        text,
        &[4],
        "4 rows of 4 numbers (a 4x4 row-major matrix)",
    )?;
    let v: Vec<f64> = rows.into_iter().flatten().collect();
    let m = Matrix4::from_row_slice(&v);
    isometry_from_matrix(&m).ok_or_else(|| {
        Error::format(
            path,
            "matrix",
            "a rigid transform (orthonormal rotation with det +1 to 5e-4, last row 0 0 0 1)",
            crate::geometry::transform::rigidity_problem(&m),
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
    crate::io::output::write_atomic(path, s.as_bytes())
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
        assert!(
            e.contains("k.txt") && e.contains("2 rows of 3, 2 numbers"),
            "{e}"
        );
    }

    /// Plausible wrong intrinsics are refused, naming the file and the entry: 585·I as a 4x4
    /// (K[2][2] = 585, cx = cy = 0), K[2][2] = 2, a principal point outside the image, skew,
    /// ragged rows.
    #[test]
    fn implausible_intrinsics_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("k.txt");
        for (text, want) in [
            ("585 0 0 0\n0 585 0 0\n0 0 585 0\n0 0 0 585\n", "K[2][2]"),
            ("585 0 320\n0 585 240\n0 0 2\n", "K[2][2]"),
            ("585 0 320\n0 585 240\n0.1 0 1\n", "K[2][0]"),
            ("585 3 320\n0 585 240\n0 0 1\n", "K[0][1]"),
            ("585 0 320 0\n0 585 240 0\n0 0 1 0\n0 0 0 2\n", "K[3][3]"),
            ("585 0 3200\n0 585 240\n0 0 1\n", "cx/cy"),
            ("585 0 320\n0 585 -5\n0 0 1\n", "cx/cy"),
            ("585 0 0\n0 585 0\n0 0 1\n", "cx/cy"),
            ("-585 0 320\n0 585 240\n0 0 1\n", "fx/fy"),
            ("585 0 320 0\n585 240\n0 0 1\n", "matrix"),
        ] {
            std::fs::write(&p, text).unwrap();
            let e = read_intrinsics(&p, 640, 480).unwrap_err().to_string();
            assert!(e.contains("k.txt") && e.contains(want), "{text:?}: {e}");
        }
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
        // 0.1 % scale is not rigid; a mirror neither; ragged rows are refused
        std::fs::write(&p, "1.001 0 0 0\n0 1.001 0 0\n0 0 1.001 0\n0 0 0 1\n").unwrap();
        let e = read_pose(&p).unwrap_err().to_string();
        assert!(
            e.contains("pose.txt") && e.contains("singular value"),
            "{e}"
        );
        std::fs::write(&p, "-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        assert!(read_pose(&p).unwrap_err().to_string().contains("det"));
        std::fs::write(&p, "1 0 0 0 0\n1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        let e = read_pose(&p).unwrap_err().to_string();
        assert!(e.contains("4 rows of 5, 3, 4, 4 numbers"), "{e}");
    }
}
