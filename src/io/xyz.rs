//! Plain XYZ text (`.xyz`, `.txt`, `.pts`): one point per line, at least 3 whitespace- or
//! comma-separated numbers `x y z`; further columns are ignored. Blank lines and lines
//! starting with `#` or `//` are skipped. A first line holding a single integer (the point
//! count, as in some `.pts` files) is skipped. Lines end with LF, CR LF or a lone CR (old Mac
//! tools). A file whose only data line holds more than 3 columns is refused: that is points
//! run together on one line far more often than a one-point cloud with attributes, and reading
//! it as one point would be silently wrong. Coordinates are taken as stored.

use super::validate::validate_cloud;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use crate::io::output::write_atomic;
use nalgebra::Point3;
use std::path::Path;

pub fn read_xyz(path: &Path) -> Result<PointCloud> {
    let bytes = crate::io::limits::read_file(path)?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        Error::format(
            path,
            "text",
            "UTF-8 / ASCII text",
            format!("invalid byte at offset {}", e.valid_up_to()),
        )
    })?;
    parse_xyz(path, text)
}

/// Parse XYZ text; `path` is used only in error messages.
pub fn parse_xyz(path: &Path, text: &str) -> Result<PointCloud> {
    let mut points = Vec::new();
    let mut first = true;
    // (line number, columns) of the first data line
    let mut first_data: Option<(usize, usize)> = None;
    let text = text.replace("\r\n", "\n").replace('\r', "\n");
    for (ln, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') || l.starts_with("//") {
            continue;
        }
        let mut toks = l
            .split(|c: char| c.is_ascii_whitespace() || c == ',')
            .filter(|t| !t.is_empty());
        let mut xyz = [0f32; 3];
        let mut k = 0;
        for t in toks.by_ref().take(3) {
            xyz[k] = t.parse().map_err(|_| {
                Error::format(
                    path,
                    format!("line {}", ln + 1),
                    "numbers x y z",
                    crate::io::output::unquoted(t),
                )
            })?;
            k += 1;
        }
        if k < 3 {
            if first && k == 1 && l.parse::<usize>().is_ok() {
                first = false;
                continue;
            }
            return Err(Error::format(
                path,
                format!("line {}", ln + 1),
                "at least 3 columns x y z",
                format!("{k} columns"),
            ));
        }
        first = false;
        first_data.get_or_insert((ln, 3 + toks.count()));
        points.push(Point3::new(xyz[0], xyz[1], xyz[2]));
    }
    if let (1, Some((ln, cols))) = (points.len(), first_data) {
        if cols > 3 {
            return Err(Error::format(
                path,
                format!("line {}", ln + 1),
                "one point per line (x y z, further columns per point)",
                format!("the only data line, with {cols} columns"),
            ));
        }
    }
    let cloud = PointCloud::from_points(points);
    validate_cloud(path, &cloud)?;
    Ok(cloud)
}

/// Write `x y z` lines with full f32 precision, atomically.
pub fn write_xyz(path: &Path, cloud: &PointCloud) -> Result<()> {
    write_atomic(path, encode_xyz(cloud).as_bytes())
}

/// `x y z` lines with full f32 precision.
pub fn encode_xyz(cloud: &PointCloud) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(cloud.len() * 30);
    for p in &cloud.points {
        let _ = writeln!(s, "{} {} {}", p.x, p.y, p.z);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_comments_extra_columns_and_counts() {
        let c = parse_xyz(
            Path::new("a.xyz"),
            "# header\n3\n1 2 3 255 0 0\n\n4.5,5,6\n  -1e-3\t0 7 0.5\n",
        )
        .unwrap();
        assert_eq!(
            c.points,
            vec![
                Point3::new(1.0, 2.0, 3.0),
                Point3::new(4.5, 5.0, 6.0),
                Point3::new(-1e-3, 0.0, 7.0)
            ]
        );
    }

    #[test]
    fn errors_name_the_line() {
        let p = Path::new("b.xyz");
        let e = parse_xyz(p, "1 2 3\n1 2\n").unwrap_err().to_string();
        assert!(e.contains("b.xyz") && e.contains("line 2"), "{e}");
        // the line is named, its content never quoted (the path may be any file)
        let e = parse_xyz(p, "1 2 3\nsecret:x 2 3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && !e.contains("secret"), "{e}");
        let e = parse_xyz(p, "# nothing\n").unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
        let e = parse_xyz(p, "1 2 3\nnan 0 0\n").unwrap_err().to_string();
        assert!(e.contains("point 1"), "{e}");
    }

    /// CR-only line ends are line ends (not one line of 9 numbers read as one point); a single
    /// data line with more than 3 columns is refused; a single x y z line is one point.
    #[test]
    fn one_line_files() {
        let p = Path::new("one.xyz");
        let c = parse_xyz(p, "1 2 3\r4 5 6\r7 8 9\r").unwrap();
        assert_eq!(c.len(), 3);
        assert_eq!(c.points[2], Point3::new(7.0, 8.0, 9.0));
        let c = parse_xyz(p, "1 2 3\r\n4 5 6\r\n").unwrap();
        assert_eq!(c.len(), 2);
        let e = parse_xyz(p, "1 2 3 4 5 6 7 8 9").unwrap_err().to_string();
        assert!(
            e.contains("one.xyz") && e.contains("line 1") && e.contains("9 columns"),
            "{e}"
        );
        let e = parse_xyz(p, "# c\n5\n1 2 3 255 0 0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3"), "{e}");
        assert_eq!(parse_xyz(p, "1 2 3\n").unwrap().len(), 1);
    }
}
