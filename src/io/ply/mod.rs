//! PLY point clouds (Stanford polygon format): ascii, binary_little_endian, binary_big_endian.
//!
//! Read: the `vertex` element gives the points. Recognised vertex properties: `x y z` (any
//! scalar type), `red green blue` (or `r g b`, `diffuse_red ...`; uchar kept as is, float
//! types taken in [0,1]), `nx ny nz`, and `intensity` / `scalar_intensity`. Any other
//! property, and any other element (faces, edges, ...) before or after `vertex`, is skipped by
//! its size, list properties included. `comment` and `obj_info` lines are ignored.
//! Coordinates are returned as stored (metres for all staged data).
//!
//! Write: binary little-endian, float `x y z`, then float `nx ny nz`, uchar `red green blue`
//! and float `intensity` for the attributes the cloud has; written atomically.

mod header;

use super::validate::validate_cloud;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use crate::io::output::write_atomic;
use header::{parse_header, roles, Element, Format, Header, Kind, Roles, Scalar};
use nalgebra::{Point3, Vector3};
use std::path::Path;

/// Collects the decoded vertex values into a cloud.
struct Sink {
    cloud: PointCloud,
    has_rgb: bool,
    has_normal: bool,
    rgb_float: [bool; 3],
}

impl Sink {
    fn new(n: usize, el: &Element, r: &Roles) -> Sink {
        let has_rgb = r.rgb.iter().all(Option::is_some);
        let has_normal = r.normal.iter().all(Option::is_some);
        let is_float = |i: Option<usize>| matches!(i.map(|i| el.props[i].kind), Some(Kind::Scalar(s)) if s.is_float());
        Sink {
            cloud: PointCloud {
                points: Vec::with_capacity(n),
                colors: has_rgb.then(|| Vec::with_capacity(n)),
                normals: has_normal.then(|| Vec::with_capacity(n)),
                intensity: r.intensity.map(|_| Vec::with_capacity(n)),
            },
            has_rgb,
            has_normal,
            rgb_float: [is_float(r.rgb[0]), is_float(r.rgb[1]), is_float(r.rgb[2])],
        }
    }

    #[inline(always)]
    fn push(&mut self, get: impl Fn(usize) -> f64, r: &Roles) {
        // Roles are Some for every attribute the sink collects (checked in `new`).
        let at = |o: Option<usize>| o.map(&get).unwrap_or(0.0);
        self.cloud.points.push(Point3::new(
            at(r.xyz[0]) as f32,
            at(r.xyz[1]) as f32,
            at(r.xyz[2]) as f32,
        ));
        if self.has_rgb {
            let c = |k: usize| {
                let v = at(r.rgb[k]);
                let v = if self.rgb_float[k] { v * 255.0 } else { v };
                v.round().clamp(0.0, 255.0) as u8
            };
            let rgb = [c(0), c(1), c(2)];
            if let Some(cs) = self.cloud.colors.as_mut() {
                cs.push(rgb);
            }
        }
        if self.has_normal {
            let n = Vector3::new(
                at(r.normal[0]) as f32,
                at(r.normal[1]) as f32,
                at(r.normal[2]) as f32,
            );
            if let Some(ns) = self.cloud.normals.as_mut() {
                ns.push(n);
            }
        }
        if let Some(is) = self.cloud.intensity.as_mut() {
            is.push(at(r.intensity) as f32);
        }
    }
}

pub fn read_ply(path: &Path) -> Result<PointCloud> {
    let data = crate::io::limits::read_file(path)?;
    parse_ply(path, &data)
}

/// Parse PLY bytes; `path` is used only in error messages.
pub fn parse_ply(path: &Path, data: &[u8]) -> Result<PointCloud> {
    let h = parse_header(path, data)?;
    let vcount = h.elements.iter().filter(|e| e.name == "vertex").count();
    if vcount != 1 {
        return Err(Error::format(
            path,
            "element vertex",
            "exactly one vertex element",
            format!("{vcount}"),
        ));
    }
    let cloud = match h.format {
        Format::Ascii => parse_ascii(path, &h, &data[h.body_start..])?,
        Format::BinaryLe => parse_binary(path, &h, &data[h.body_start..], false)?,
        Format::BinaryBe => parse_binary(path, &h, &data[h.body_start..], true)?,
    };
    validate_cloud(path, &cloud)?;
    Ok(cloud)
}

fn truncated(path: &Path, el: &Element, i: usize, need: String, found: usize) -> Error {
    Error::format(
        path,
        format!("element {} (instance {i} of {})", el.name, el.count),
        format!("{need} (file truncated?)"),
        format!("{found} bytes left"),
    )
}

fn parse_binary(path: &Path, h: &Header, body: &[u8], big: bool) -> Result<PointCloud> {
    let mut pos = 0usize;
    let mut out = None;
    for el in &h.elements {
        let rest = &body[pos..];
        if el.name == "vertex" {
            let r = roles(path, el)?;
            let Some(stride) = el.fixed_stride() else {
                // a list property (e.g. a scanner's per-vertex index list): walk each vertex
                let mut sink = Sink::new(el.count.min(rest.len()), el, &r);
                let mut vals = Vec::with_capacity(el.props.len());
                let mut p = 0usize;
                for i in 0..el.count {
                    vals.clear();
                    p = walk_binary_instance(path, el, i, rest, p, big, &mut vals)?;
                    sink.push(|k| vals[k], &r);
                }
                out = Some(sink.cloud);
                pos += p;
                continue;
            };
            let need = stride.saturating_mul(el.count);
            if rest.len() < need {
                return Err(Error::format(
                    path,
                    "vertex data",
                    format!(
                        "{} vertices x {stride} bytes = {need} bytes (file truncated?)",
                        el.count
                    ),
                    format!("{} bytes", rest.len()),
                ));
            }
            let mut offs = Vec::with_capacity(el.props.len());
            let mut o = 0;
            for p in &el.props {
                // fixed_stride excludes lists
                let s = match p.kind {
                    Kind::Scalar(s) => s,
                    Kind::List { count, .. } => count,
                };
                offs.push((o, s));
                o += s.size();
            }
            let mut sink = Sink::new(el.count, el, &r);
            // Fast path for the common float32 x y z at the start of each vertex.
            let plain_f32 = !sink.has_rgb
                && !sink.has_normal
                && r.intensity.is_none()
                && r.xyz == [Some(0), Some(1), Some(2)]
                && offs[..3].iter().all(|&(_, s)| s == Scalar::F32);
            if plain_f32 {
                let rd = |b: &[u8]| {
                    let a = [b[0], b[1], b[2], b[3]];
                    if big {
                        f32::from_be_bytes(a)
                    } else {
                        f32::from_le_bytes(a)
                    }
                };
                sink.cloud.points.extend(
                    rest[..need]
                        .chunks_exact(stride)
                        .map(|v| Point3::new(rd(&v[0..4]), rd(&v[4..8]), rd(&v[8..12]))),
                );
            } else {
                for v in rest[..need].chunks_exact(stride) {
                    sink.push(
                        |k| {
                            let (o, s) = offs[k];
                            s.read(&v[o..], big)
                        },
                        &r,
                    );
                }
            }
            out = Some(sink.cloud);
            pos += need;
        } else if let Some(stride) = el.fixed_stride() {
            let need = stride.saturating_mul(el.count);
            if rest.len() < need {
                return Err(truncated(
                    path,
                    el,
                    rest.len() / stride.max(1),
                    format!("{need} bytes"),
                    rest.len(),
                ));
            }
            pos += need;
        } else {
            // Lists: walk instance by instance.
            let mut p = 0usize;
            let mut vals = Vec::new();
            for i in 0..el.count {
                vals.clear();
                p = walk_binary_instance(path, el, i, rest, p, big, &mut vals)?;
            }
            pos += p;
        }
    }
    out.ok_or_else(|| Error::format(path, "element vertex", "vertex data", "none"))
}

/// Read instance `i` of `el` starting at byte `p` of `rest`: each scalar property's value is
/// pushed to `vals` (NaN for a list, which is skipped by its length). Returns the byte after
/// the instance.
fn walk_binary_instance(
    path: &Path,
    el: &Element,
    i: usize,
    rest: &[u8],
    mut p: usize,
    big: bool,
    vals: &mut Vec<f64>,
) -> Result<usize> {
    for prop in &el.props {
        match prop.kind {
            Kind::Scalar(s) => {
                let b = rest.get(p..p + s.size()).ok_or_else(|| {
                    truncated(
                        path,
                        el,
                        i,
                        format!("{} bytes of property {}", s.size(), prop.name),
                        rest.len().saturating_sub(p),
                    )
                })?;
                vals.push(s.read(b, big));
                p += s.size();
            }
            Kind::List { count, item } => {
                if rest.len() < p + count.size() {
                    return Err(truncated(
                        path,
                        el,
                        i,
                        "a list length".into(),
                        rest.len().saturating_sub(p),
                    ));
                }
                let n = count.read(&rest[p..], big);
                if n < 0.0 {
                    return Err(Error::format(
                        path,
                        format!("element {} instance {i} list {}", el.name, prop.name),
                        "a non-negative length",
                        format!("{n}"),
                    ));
                }
                p = (n as usize)
                    .checked_mul(item.size())
                    .and_then(|b| b.checked_add(p + count.size()))
                    .filter(|&e| e <= rest.len())
                    .ok_or_else(|| {
                        truncated(
                            path,
                            el,
                            i,
                            format!("a list of {n} items"),
                            rest.len().saturating_sub(p),
                        )
                    })?;
                vals.push(f64::NAN);
            }
        }
    }
    Ok(p)
}

fn parse_ascii(path: &Path, h: &Header, body: &[u8]) -> Result<PointCloud> {
    let text = std::str::from_utf8(body).map_err(|e| {
        Error::format(
            path,
            "ascii body",
            "UTF-8 / ASCII text",
            format!("invalid byte at offset {}", e.valid_up_to()),
        )
    })?;
    let mut toks = text.split_ascii_whitespace();
    let mut out = None;
    let mut vals: Vec<f64> = Vec::new();
    for el in &h.elements {
        let is_vertex = el.name == "vertex";
        let r = if is_vertex {
            Some(roles(path, el)?)
        } else {
            None
        };
        // Each ascii vertex takes at least 2 bytes: cap the capacity a header can ask for.
        let cap = el.count.min(body.len() / 2);
        let mut sink = r.as_ref().map(|r| Sink::new(cap, el, r));
        // An element without properties has nothing to read, whatever its count (looping
        // over a count of 10^18 would never end); one with properties needs a token each.
        let count = if el.props.is_empty() { 0 } else { el.count };
        crate::io::limits::check_count(
            path,
            &format!("element {} count", el.name),
            (count as u64).saturating_mul(el.props.len() as u64),
            1,
            body.len() as u64,
        )?;
        for i in 0..count {
            vals.clear();
            for prop in &el.props {
                let mut next = |what: &str| -> Result<f64> {
                    let t = toks.next().ok_or_else(|| {
                        Error::format(
                            path,
                            format!("element {} instance {i} property {}", el.name, prop.name),
                            format!("{what} (file truncated?)"),
                            "end of file",
                        )
                    })?;
                    t.parse::<f64>().map_err(|_| {
                        Error::format(
                            path,
                            format!("element {} instance {i} property {}", el.name, prop.name),
                            what.to_string(),
                            crate::io::output::unquoted(t),
                        )
                    })
                };
                match prop.kind {
                    Kind::Scalar(_) => vals.push(next("a number")?),
                    Kind::List { .. } => {
                        let n = next("a list length")?;
                        if !(0.0..=1e9).contains(&n) {
                            return Err(Error::format(
                                path,
                                format!("element {} instance {i} list {}", el.name, prop.name),
                                "a non-negative length",
                                format!("{n}"),
                            ));
                        }
                        for _ in 0..n as usize {
                            next("a list item")?;
                        }
                        vals.push(f64::NAN);
                    }
                }
            }
            if let (Some(s), Some(r)) = (sink.as_mut(), r.as_ref()) {
                s.push(|k| vals[k], r);
            }
        }
        if let Some(s) = sink {
            out = Some(s.cloud);
        }
    }
    out.ok_or_else(|| Error::format(path, "element vertex", "vertex data", "none"))
}

/// Encode a cloud as binary little-endian PLY bytes.
pub fn encode_ply(cloud: &PointCloud) -> Vec<u8> {
    let mut head = String::from("ply\nformat binary_little_endian 1.0\ncomment cgenreg\n");
    head += &format!("element vertex {}\n", cloud.len());
    head += "property float x\nproperty float y\nproperty float z\n";
    let mut stride = 12;
    if cloud.normals.is_some() {
        head += "property float nx\nproperty float ny\nproperty float nz\n";
        stride += 12;
    }
    if cloud.colors.is_some() {
        head += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
        stride += 3;
    }
    if cloud.intensity.is_some() {
        head += "property float intensity\n";
        stride += 4;
    }
    head += "end_header\n";
    let mut buf = Vec::with_capacity(head.len() + stride * cloud.len());
    buf.extend_from_slice(head.as_bytes());
    for (i, p) in cloud.points.iter().enumerate() {
        for v in [p.x, p.y, p.z] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        if let Some(ns) = &cloud.normals {
            let n = ns.get(i).copied().unwrap_or_else(Vector3::zeros);
            for v in [n.x, n.y, n.z] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
        }
        if let Some(cs) = &cloud.colors {
            buf.extend_from_slice(&cs.get(i).copied().unwrap_or([0; 3]));
        }
        if let Some(is) = &cloud.intensity {
            buf.extend_from_slice(&is.get(i).copied().unwrap_or(0.0).to_le_bytes());
        }
    }
    buf
}

/// Write a binary little-endian PLY with every attribute the cloud has, atomically.
/// Attribute arrays whose length differs from the point count are rejected.
pub fn write_ply(path: &Path, cloud: &PointCloud) -> Result<()> {
    let n = cloud.len();
    for (name, len) in [
        ("colors", cloud.colors.as_ref().map(Vec::len)),
        ("normals", cloud.normals.as_ref().map(Vec::len)),
        ("intensity", cloud.intensity.as_ref().map(Vec::len)),
    ] {
        if let Some(l) = len.filter(|&l| l != n) {
            return Err(Error::Shape(format!(
                "writing {}: {name} has {l} entries for {n} points",
                path.display()
            )));
        }
    }
    write_atomic(path, &encode_ply(cloud))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> PointCloud {
        let n = 7;
        PointCloud {
            points: (0..n)
                .map(|i| Point3::new(i as f32 * 0.5, -1.25 * i as f32, 3.0 + i as f32))
                .collect(),
            colors: Some(
                (0..n)
                    .map(|i| [i as u8, 100 + i as u8, 255 - i as u8])
                    .collect(),
            ),
            normals: Some(
                (0..n)
                    .map(|i| Vector3::new(0.0, (i as f32).sin(), (i as f32).cos()))
                    .collect(),
            ),
            intensity: Some((0..n).map(|i| i as f32 * 0.1).collect()),
        }
    }

    #[test]
    fn write_read_round_trip_keeps_all_attributes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.ply");
        let c = sample();
        write_ply(&p, &c).unwrap();
        assert_eq!(read_ply(&p).unwrap(), c);
        let bare = PointCloud::from_points(c.points.clone());
        write_ply(&p, &bare).unwrap();
        assert_eq!(read_ply(&p).unwrap(), bare);
    }

    /// The same cloud in ascii, little- and big-endian with double coordinates, mixed int
    /// properties, unknown properties and face elements before and after the vertices.
    #[test]
    fn all_encodings_and_skipped_elements() {
        let pts = [[1.5f64, -2.0, 0.25], [0.0, 1e-3, 7.0], [-3.0, 4.0, 5.5]];
        let head = |fmt: &str| {
            format!(
                "ply\nformat {fmt} 1.0\ncomment made by a test\nobj_info x\n\
                 element camera 1\nproperty float k\nproperty list uchar int ids\n\
                 element vertex 3\nproperty double x\nproperty short junk\nproperty double y\n\
                 property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
                 property float scalar_intensity\n\
                 element face 2\nproperty list uchar int vertex_indices\nproperty int flags\n\
                 end_header\n"
            )
        };
        let mut ascii = head("ascii");
        ascii += "0.5 2 10 20\n";
        for (i, p) in pts.iter().enumerate() {
            ascii += &format!("{} -7 {} {} {} 20 30 {}\n", p[0], p[1], p[2], i * 10, i);
        }
        ascii += "3 0 1 2 9\n4 0 1 2 0 9\n";
        let bin = |big: bool| {
            let mut b = head(if big {
                "binary_big_endian"
            } else {
                "binary_little_endian"
            })
            .into_bytes();
            macro_rules! put {
                ($v:expr) => {
                    if big {
                        b.extend_from_slice(&$v.to_be_bytes())
                    } else {
                        b.extend_from_slice(&$v.to_le_bytes())
                    }
                };
            }
            put!(0.5f32);
            b.push(2);
            put!(10i32);
            put!(20i32);
            for (i, p) in pts.iter().enumerate() {
                put!(p[0]);
                put!(-7i16);
                put!(p[1]);
                put!(p[2]);
                b.extend_from_slice(&[(i * 10) as u8, 20, 30]);
                put!(i as f32);
            }
            for k in [3u8, 4] {
                b.push(k);
                for j in 0..k as i32 {
                    put!(j);
                }
                put!(9i32);
            }
            b
        };
        for (name, bytes) in [
            ("ascii", ascii.into_bytes()),
            ("le", bin(false)),
            ("be", bin(true)),
        ] {
            let c = parse_ply(Path::new(name), &bytes).unwrap();
            assert_eq!(c.len(), 3, "{name}");
            for (a, p) in c.points.iter().zip(&pts) {
                assert_eq!([a.x, a.y, a.z], [p[0] as f32, p[1] as f32, p[2] as f32]);
            }
            assert_eq!(c.colors.as_ref().unwrap()[2], [20, 20, 30], "{name}");
            assert_eq!(c.intensity.as_ref().unwrap(), &vec![0.0, 1.0, 2.0]);
            assert!(c.normals.is_none());
            // Truncating the binary faces after the vertices is still detected.
            if name != "ascii" {
                let e = parse_ply(Path::new(name), &bytes[..bytes.len() - 3]).unwrap_err();
                assert!(e.to_string().contains("face"), "{e}");
            }
        }
    }

    /// A vertex element with list properties (as several scanners' tools write: a per-vertex
    /// index list before y, a float list at the end) reads in ascii, little and big endian;
    /// the lists are skipped by their lengths, and a truncated list is an error.
    #[test]
    fn vertex_list_properties_are_skipped() {
        let pts = [[1.5f32, -2.0, 0.25], [0.0, 1e-3, 7.0], [-3.0, 4.0, 5.5]];
        let lists: [&[i32]; 3] = [&[4, 5], &[], &[1, 2, 3, 4, 5]];
        let head = |fmt: &str| {
            format!(
                "ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\n\
                 property list uchar int view_ids\nproperty float y\nproperty float z\n\
                 property uchar red\nproperty uchar green\nproperty uchar blue\n\
                 property list ushort float weights\nend_header\n"
            )
        };
        let mut ascii = head("ascii");
        for (i, p) in pts.iter().enumerate() {
            let l: Vec<String> = lists[i].iter().map(|v| v.to_string()).collect();
            ascii += &format!(
                "{} {} {} {} {} {i} 2 3 1 0.5\n",
                p[0],
                lists[i].len(),
                l.join(" "),
                p[1],
                p[2]
            );
        }
        let bin = |big: bool| {
            let mut b = head(if big {
                "binary_big_endian"
            } else {
                "binary_little_endian"
            })
            .into_bytes();
            macro_rules! put {
                ($v:expr) => {
                    if big {
                        b.extend_from_slice(&$v.to_be_bytes())
                    } else {
                        b.extend_from_slice(&$v.to_le_bytes())
                    }
                };
            }
            for (i, p) in pts.iter().enumerate() {
                put!(p[0]);
                b.push(lists[i].len() as u8);
                for v in lists[i] {
                    put!(*v);
                }
                put!(p[1]);
                put!(p[2]);
                b.extend_from_slice(&[i as u8, 2, 3]);
                put!(1u16);
                put!(0.5f32);
            }
            b
        };
        for (name, bytes) in [
            ("ascii", ascii.into_bytes()),
            ("le", bin(false)),
            ("be", bin(true)),
        ] {
            let c = parse_ply(Path::new(name), &bytes).unwrap();
            assert_eq!(c.len(), 3, "{name}");
            for (a, p) in c.points.iter().zip(&pts) {
                assert_eq!([a.x, a.y, a.z], *p, "{name}");
            }
            assert_eq!(c.colors.as_ref().unwrap()[2], [2, 2, 3], "{name}");
            if name != "ascii" {
                let e = parse_ply(Path::new("cut.ply"), &bytes[..bytes.len() - 5])
                    .unwrap_err()
                    .to_string();
                assert!(e.contains("cut.ply") && e.contains("instance 2"), "{e}");
            }
        }
    }

    /// The format line must name the version 1.0.
    #[test]
    fn format_version_is_required() {
        for line in ["format ascii 2.0", "format ascii", "format ascii 1.0 extra"] {
            let text = format!(
                "ply\n{line}\nelement vertex 1\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n1 2 3\n"
            );
            let e = parse_ply(Path::new("v.ply"), text.as_bytes())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("v.ply") && e.contains("header line 2") && e.contains("1.0"),
                "{e}"
            );
        }
    }

    #[test]
    fn header_errors() {
        let p = Path::new("h.ply");
        let e = parse_ply(p, b"PLY\nformat ascii 1.0\n").unwrap_err();
        assert!(e.to_string().contains("magic"), "{e}");
        let e = parse_ply(
            p,
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("end_header"), "{e}");
        let e = parse_ply(
            p,
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("x, y and z"), "{e}");
        let e = parse_ply(
            p,
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("header line 4"), "{e}");
        let e = parse_ply(
            p,
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
              property float z\nend_header\n1 2 3\n4 nan 6\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("point 1"), "{e}");
    }

    #[test]
    fn staged_plys_have_manifest_point_counts() {
        let Some(root) = crate::testing::test_data_root() else {
            return;
        };
        let m = root.join("3dmatch-redkitchen");
        for (rel, n) in [
            ("teaser-plusplus/cloud_bin_0.ply", 258_342),
            ("teaser-plusplus/cloud_bin_4.ply", 313_395),
            ("3dsmoothnet/cloud_bin_1.ply", 268_977),
            (
                "dip/threed_match_7-scenes-redkitchen_cloud_bin_5.ply",
                313_910,
            ),
        ] {
            let c = read_ply(&m.join(rel)).unwrap();
            assert_eq!(c.len(), n, "{rel}");
            let (lo, hi) = c.bounds().unwrap();
            // Fragments are cropped to a 3 m cube in front of the camera.
            assert!(
                lo.z > 0.0 && hi.z < 4.0 && hi.x - lo.x < 3.5,
                "{rel}: {lo} {hi}"
            );
        }
        let lidar = root.join("small-gicp-lidar-pair");
        for (rel, n) in [("source.ply", 69_792), ("target.ply", 69_088)] {
            let c = read_ply(&lidar.join(rel)).unwrap();
            assert_eq!(c.len(), n, "{rel}");
            let it = c.intensity.as_ref().unwrap();
            assert!(it.iter().any(|&v| v != it[0]), "{rel}: constant intensity");
        }
    }
}
