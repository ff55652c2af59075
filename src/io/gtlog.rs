//! 3DMatch `gt.log` and `gt.info`.
//!
//! gt.log: blocks of 5 lines, a header `i j N` (N = number of fragments of the scene) and a
//! 4x4 matrix T with **p_i = T * p_j**: fragment j is the source, fragment i the target, and
//! T is `target_from_source`. gt.info: the same header and a 6x6 information matrix (used by
//! the RMSE-based recall of Choi et al.; it is not a pose).

use crate::error::{Error, Result};
use crate::geometry::transform::isometry_from_matrix;
use nalgebra::{Isometry3, Matrix4, Matrix6};
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct GtEntry {
    /// Fragment i of the header (target).
    pub target: usize,
    /// Fragment j of the header (source).
    pub source: usize,
    /// Third header field: the number of fragments in the scene.
    pub n_fragments: usize,
    pub target_from_source: Isometry3<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct GtInfo {
    pub target: usize,
    pub source: usize,
    pub n_fragments: usize,
    pub information: Matrix6<f64>,
}

struct Block {
    header: [usize; 3],
    values: Vec<f64>,
    line: usize,
}

fn parse_blocks(path: &Path, text: &str, rows: usize, cols: usize) -> Result<Vec<Block>> {
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .collect();
    if !lines.len().is_multiple_of(rows + 1) {
        return Err(Error::format(
            path,
            "layout",
            format!(
                "blocks of {} non-empty lines (header + {rows} matrix rows)",
                rows + 1
            ),
            format!("{} non-empty lines", lines.len()),
        ));
    }
    let mut out = Vec::new();
    for chunk in lines.chunks(rows + 1) {
        let (ln, head) = chunk[0];
        let h: Vec<&str> = head.split_whitespace().collect();
        let parsed: Option<Vec<usize>> = h.iter().map(|t| t.parse().ok()).collect();
        let header = match parsed.as_deref() {
            Some([a, b, c]) => [*a, *b, *c],
            _ => {
                return Err(Error::format(
                    path,
                    format!("line {} (header)", ln + 1),
                    "three integers `i j N`",
                    format!("{head:?}"),
                ))
            }
        };
        let mut values = Vec::with_capacity(rows * cols);
        for &(lr, row) in &chunk[1..] {
            let nums: Vec<&str> = row.split_whitespace().collect();
            if nums.len() != cols {
                return Err(Error::format(
                    path,
                    format!("line {}", lr + 1),
                    format!("{cols} numbers"),
                    format!("{} fields", nums.len()),
                ));
            }
            for t in nums {
                let v: f64 = t
                    .parse()
                    .ok()
                    .filter(|v: &f64| v.is_finite())
                    .ok_or_else(|| {
                        Error::format(
                            path,
                            format!("line {}", lr + 1),
                            "a finite number",
                            crate::io::output::unquoted(t),
                        )
                    })?;
                values.push(v);
            }
        }
        out.push(Block {
            header,
            values,
            line: ln + 1,
        });
    }
    Ok(out)
}

/// gt.log entries. A pair `i j` listed twice is refused unless both matrices agree (every
/// entry within 1e-9): which one a reader would take is otherwise arbitrary.
pub fn parse_gt_log(path: &Path, text: &str) -> Result<Vec<GtEntry>> {
    let mut seen: std::collections::HashMap<(usize, usize), (usize, Matrix4<f64>)> =
        Default::default();
    let mut out = Vec::new();
    for b in parse_blocks(path, text, 4, 4)? {
        let m = Matrix4::from_row_slice(&b.values);
        let t = isometry_from_matrix(&m).ok_or_else(|| {
            Error::format(
                path,
                format!("block at line {}", b.line),
                "a rigid 4x4 transform (rotation to 5e-4, last row 0 0 0 1)",
                crate::geometry::transform::rigidity_problem(&m),
            )
        })?;
        let key = (b.header[0], b.header[1]);
        if let Some((line, first)) = seen.get(&key) {
            if (first - m).amax() > 1e-9 {
                return Err(Error::format(
                    path,
                    format!("block at line {} (pair {} {})", b.line, key.0, key.1),
                    format!("no second, different matrix for a pair (first at line {line})"),
                    format!("matrices differing by {:.3e}", (first - m).amax()),
                ));
            }
            continue;
        }
        seen.insert(key, (b.line, m));
        out.push(GtEntry {
            target: b.header[0],
            source: b.header[1],
            n_fragments: b.header[2],
            target_from_source: t,
        });
    }
    Ok(out)
}

pub fn read_gt_log(path: &Path) -> Result<Vec<GtEntry>> {
    let text = crate::io::limits::read_text(path)?;
    parse_gt_log(path, &text)
}

pub fn read_gt_info(path: &Path) -> Result<Vec<GtInfo>> {
    let text = crate::io::limits::read_text(path)?;
    parse_gt_info(path, &text)
}

/// [`read_gt_info`] on the file's text; `path` is used only in error messages.
pub fn parse_gt_info(path: &Path, text: &str) -> Result<Vec<GtInfo>> {
    Ok(parse_blocks(path, text, 6, 6)?
        .into_iter()
        .map(|b| GtInfo {
            target: b.header[0],
            source: b.header[1],
            n_fragments: b.header[2],
            information: Matrix6::from_row_slice(&b.values),
        })
        .collect())
}

/// Format entries in the gt.log layout (what 3DMatch evaluation scripts read for results).
pub fn format_gt_log(entries: &[GtEntry]) -> String {
    let mut s = String::new();
    for e in entries {
        s.push_str(&format!(
            "{}\t {}\t {}\t\n",
            e.target, e.source, e.n_fragments
        ));
        let m = e.target_from_source.to_homogeneous();
        for r in 0..4 {
            let row: Vec<String> = (0..4).map(|c| format!("{:.8e}", m[(r, c)])).collect();
            s.push_str(&row.join("\t "));
            s.push_str("\t\n");
        }
    }
    s
}

pub fn write_gt_log(path: &Path, entries: &[GtEntry]) -> Result<()> {
    crate::io::output::write_atomic(path, format_gt_log(entries).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn roundtrip() {
        let t = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.3),
        );
        let e = vec![GtEntry {
            target: 0,
            source: 5,
            n_fragments: 60,
            target_from_source: t,
        }];
        let text = format_gt_log(&e);
        let back = parse_gt_log(Path::new("x.log"), &text).unwrap();
        assert_eq!(back[0].target, 0);
        assert_eq!(back[0].source, 5);
        assert!((back[0].target_from_source.to_homogeneous() - t.to_homogeneous()).amax() < 1e-7);
    }

    #[test]
    fn errors_name_line() {
        let bad = "0 1 60\n1 0 0 0\n0 1 0 0\n0 0 1 x\n0 0 0 1\n";
        let e = parse_gt_log(Path::new("gt.log"), bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("gt.log") && e.contains("line 4"), "{e}");
        let short = "0 1 60\n1 0 0 0\n0 1 0 0\n";
        assert!(parse_gt_log(Path::new("gt.log"), short).is_err());
        // a ragged row
        let ragged = "0 1 60\n1 0 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n";
        let e = parse_gt_log(Path::new("gt.log"), ragged)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("4 numbers"), "{e}");
    }

    /// One pair listed twice: refused when the matrices differ (naming both blocks), one
    /// entry when they agree; a 0.1 % scale is not rigid.
    #[test]
    fn duplicate_and_scaled_entries() {
        let id = "0 1 60\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
        let moved = "0 1 60\n1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
        let e = parse_gt_log(Path::new("gt.log"), &format!("{id}{moved}"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 6") && e.contains("first at line 1"), "{e}");
        let both = parse_gt_log(Path::new("gt.log"), &format!("{id}{id}")).unwrap();
        assert_eq!(both.len(), 1);
        let scaled = "0 1 60\n1.002 0 0 0\n0 1.002 0 0\n0 0 1.002 0\n0 0 0 1\n";
        let e = parse_gt_log(Path::new("gt.log"), scaled)
            .unwrap_err()
            .to_string();
        assert!(e.contains("singular value"), "{e}");
    }
}
