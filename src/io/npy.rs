//! NumPy `.npy` and `.npz` arrays of float32 / float64.
//!
//! NPY versions 1, 2 and 3; dtypes `<f4 <f8 >f4 >f8` (and `=`/`|` native prefixes);
//! `fortran_order` true or false. Arrays are returned in C (row-major) order whatever the file
//! order, with their original precision. `.npz` is a zip of `name.npy` entries (stored or
//! deflated). Clouds are (N,3) arrays of x,y,z in metres; poses are (4,4) homogeneous
//! matrices, applied as `p' = M * p` (GeoTransformer's `gt.npy` is `ref_from_src`).

use super::validate::validate_cloud;
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use crate::geometry::transform::isometry_from_matrix;
use crate::io::output::write_atomic;
use nalgebra::{Isometry3, Matrix4, Point3};
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub enum NpyData {
    F32(Vec<f32>),
    F64(Vec<f64>),
}

/// An n-dimensional float array in C order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: NpyData,
}

impl NpyArray {
    pub fn len(&self) -> usize {
        match &self.data {
            NpyData::F32(v) => v.len(),
            NpyData::F64(v) => v.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn to_f64(&self) -> Vec<f64> {
        match &self.data {
            NpyData::F32(v) => v.iter().map(|&x| x as f64).collect(),
            NpyData::F64(v) => v.clone(),
        }
    }
    pub fn to_f32(&self) -> Vec<f32> {
        match &self.data {
            NpyData::F32(v) => v.clone(),
            NpyData::F64(v) => v.iter().map(|&x| x as f32).collect(),
        }
    }
    pub fn dtype_name(&self) -> &'static str {
        match self.data {
            NpyData::F32(_) => "float32",
            NpyData::F64(_) => "float64",
        }
    }
    /// (rows, cols) of a 2-D array.
    pub fn rows_cols(&self) -> Option<(usize, usize)> {
        match self.shape[..] {
            [r, c] => Some((r, c)),
            _ => None,
        }
    }
}

pub(crate) fn shape_str(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Decode raw array bytes (shared with the pickle reader). `dtype` is (kind, size,
/// big_endian) as in a NumPy dtype string (`'f'`, 4 or 8); `field` names the array in errors.
pub(crate) fn decode_array(
    path: &Path,
    field: &str,
    dtype: (char, usize, bool),
    shape: &[usize],
    fortran: bool,
    bytes: &[u8],
) -> Result<NpyArray> {
    let (kind, size, big_endian) = dtype;
    if kind != 'f' || !(size == 4 || size == 8) {
        return Err(Error::format(
            path,
            format!("{field} dtype"),
            "float32 or float64",
            format!("{kind}{size}"),
        ));
    }
    let count = shape
        .iter()
        .try_fold(1usize, |a, &s| a.checked_mul(s))
        .ok_or_else(|| {
            Error::format(
                path,
                format!("{field} shape"),
                "a sane shape",
                shape_str(shape),
            )
        })?;
    let need = count.saturating_mul(size);
    if bytes.len() < need {
        return Err(Error::format(
            path,
            format!("{field} data"),
            format!(
                "{need} bytes for shape {} of f{size} (file truncated?)",
                shape_str(shape)
            ),
            format!("{} bytes", bytes.len()),
        ));
    }
    if bytes.len() > need {
        return Err(Error::format(
            path,
            format!("{field} data"),
            format!("{need} bytes for shape {} of f{size}", shape_str(shape)),
            format!("{} bytes", bytes.len()),
        ));
    }
    let bytes = &bytes[..need];
    let mut data = if size == 4 {
        NpyData::F32(
            bytes
                .chunks_exact(4)
                .map(|c| {
                    let a = [c[0], c[1], c[2], c[3]];
                    if big_endian {
                        f32::from_be_bytes(a)
                    } else {
                        f32::from_le_bytes(a)
                    }
                })
                .collect(),
        )
    } else {
        NpyData::F64(
            bytes
                .chunks_exact(8)
                .map(|c| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(c);
                    if big_endian {
                        f64::from_be_bytes(a)
                    } else {
                        f64::from_le_bytes(a)
                    }
                })
                .collect(),
        )
    };
    if fortran && shape.len() > 1 {
        data = match data {
            NpyData::F32(v) => NpyData::F32(fortran_to_c(&v, shape)),
            NpyData::F64(v) => NpyData::F64(fortran_to_c(&v, shape)),
        };
    }
    Ok(NpyArray {
        shape: shape.to_vec(),
        data,
    })
}

/// Reorder a column-major (first index fastest) buffer into row-major.
fn fortran_to_c<T: Copy + Default>(v: &[T], shape: &[usize]) -> Vec<T> {
    let nd = shape.len();
    let mut f_strides = vec![1usize; nd];
    for d in 1..nd {
        f_strides[d] = f_strides[d - 1] * shape[d - 1];
    }
    let mut out = vec![T::default(); v.len()];
    let mut idx = vec![0usize; nd];
    for o in out.iter_mut() {
        let src: usize = idx.iter().zip(&f_strides).map(|(i, s)| i * s).sum();
        *o = v[src];
        // Advance the C-order multi-index (last index fastest).
        for d in (0..nd).rev() {
            idx[d] += 1;
            if idx[d] < shape[d] {
                break;
            }
            idx[d] = 0;
        }
    }
    out
}

/// A value of the Python-literal header dict.
#[derive(Debug, PartialEq)]
enum Lit {
    Str(String),
    Bool(bool),
    Int(usize),
    Tuple(Vec<Lit>),
}

struct LitParser<'a> {
    s: &'a [u8],
    i: usize,
    /// Tuple nesting so far; a header nesting deeper than the limit is refused (recursion).
    depth: usize,
}

impl LitParser<'_> {
    fn ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
            self.i += 1;
        }
    }
    fn eat(&mut self, c: u8) -> bool {
        self.ws();
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn value(&mut self) -> Option<Lit> {
        self.ws();
        let c = *self.s.get(self.i)?;
        match c {
            b'\'' | b'"' => {
                let start = self.i + 1;
                let end = start + self.s[start..].iter().position(|&x| x == c)?;
                self.i = end + 1;
                Some(Lit::Str(
                    String::from_utf8_lossy(&self.s[start..end]).into(),
                ))
            }
            b'(' => {
                self.i += 1;
                self.depth += 1;
                if self.depth > 32 {
                    return None; // shapes nest one level; this is not an NPY header
                }
                let mut items = Vec::new();
                loop {
                    if self.eat(b')') {
                        self.depth -= 1;
                        return Some(Lit::Tuple(items));
                    }
                    items.push(self.value()?);
                    if !self.eat(b',') {
                        self.depth -= 1;
                        return self.eat(b')').then_some(Lit::Tuple(items));
                    }
                }
            }
            b'0'..=b'9' => {
                let start = self.i;
                while self.i < self.s.len() && self.s[self.i].is_ascii_digit() {
                    self.i += 1;
                }
                // Python 2 era headers may write longs as `3L`.
                if self.s.get(self.i) == Some(&b'L') {
                    self.i += 1;
                }
                std::str::from_utf8(&self.s[start..self.i])
                    .ok()?
                    .trim_end_matches('L')
                    .parse()
                    .ok()
                    .map(Lit::Int)
            }
            _ if self.s[self.i..].starts_with(b"True") => {
                self.i += 4;
                Some(Lit::Bool(true))
            }
            _ if self.s[self.i..].starts_with(b"False") => {
                self.i += 5;
                Some(Lit::Bool(false))
            }
            _ => None,
        }
    }
    fn dict(&mut self) -> Option<Vec<(String, Lit)>> {
        if !self.eat(b'{') {
            return None;
        }
        let mut out = Vec::new();
        loop {
            if self.eat(b'}') {
                return Some(out);
            }
            let Lit::Str(k) = self.value()? else {
                return None;
            };
            if !self.eat(b':') {
                return None;
            }
            out.push((k, self.value()?));
            if !self.eat(b',') {
                return self.eat(b'}').then_some(out);
            }
        }
    }
}

/// Parse a dtype string such as `<f4` into (kind, size, big_endian).
pub(crate) fn parse_descr(d: &str) -> Option<(char, usize, bool)> {
    let (big, rest) = match d.as_bytes().first()? {
        b'<' => (false, &d[1..]),
        b'>' => (true, &d[1..]),
        b'=' | b'|' => (cfg!(target_endian = "big"), &d[1..]),
        _ => (cfg!(target_endian = "big"), d),
    };
    let kind = rest.chars().next()?;
    let size = rest[kind.len_utf8()..].parse().ok()?;
    Some((kind, size, big))
}

pub fn read_npy(path: &Path) -> Result<NpyArray> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_npy(path, &bytes)
}

/// Parse NPY bytes; `path` is used only in error messages.
pub fn parse_npy(path: &Path, bytes: &[u8]) -> Result<NpyArray> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(Error::format(
            path,
            "magic",
            "\\x93NUMPY",
            format!(
                "{:?}",
                String::from_utf8_lossy(&bytes[..bytes.len().min(6)])
            ),
        ));
    }
    let major = bytes[6];
    let (hlen, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10usize),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => {
            return Err(Error::format(
                path,
                "version",
                "NPY version 1, 2 or 3",
                format!("{major}.{}", bytes[7]),
            ))
        }
    };
    let end = start.saturating_add(hlen);
    if bytes.len() < end {
        return Err(Error::format(
            path,
            "header",
            format!("{hlen} header bytes (file truncated?)"),
            format!("{} bytes", bytes.len().saturating_sub(start)),
        ));
    }
    let header = &bytes[start..end];
    let bad_header = || {
        Error::format(
            path,
            "header",
            "a dict with 'descr', 'fortran_order' and 'shape'",
            format!("{:?}", String::from_utf8_lossy(header).trim_end()),
        )
    };
    let dict = LitParser {
        s: header,
        i: 0,
        depth: 0,
    }
    .dict()
    .ok_or_else(bad_header)?;
    let get = |k: &str| dict.iter().find(|(n, _)| n == k).map(|(_, v)| v);
    let (Some(Lit::Str(descr)), Some(Lit::Bool(fortran)), Some(Lit::Tuple(shape))) =
        (get("descr"), get("fortran_order"), get("shape"))
    else {
        return Err(bad_header());
    };
    let shape: Vec<usize> = shape
        .iter()
        .map(|d| match d {
            Lit::Int(n) => Some(*n),
            _ => None,
        })
        .collect::<Option<_>>()
        .ok_or_else(bad_header)?;
    let (kind, size, big) = parse_descr(descr).ok_or_else(|| {
        Error::format(
            path,
            "descr",
            "a dtype like '<f4' or '<f8'",
            format!("{descr:?}"),
        )
    })?;
    decode_array(
        path,
        "array",
        (kind, size, big),
        &shape,
        *fortran,
        &bytes[end..],
    )
}

/// Read every `name.npy` entry of an `.npz` archive, keyed by `name`.
pub fn read_npz(path: &Path) -> Result<BTreeMap<String, NpyArray>> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_npz(path, &bytes)
}

/// Parse the bytes of an `.npz` archive; every entry's decoded size is capped by
/// [`crate::io::limits::max_decoded_bytes`] whatever its zip header claims.
pub fn parse_npz(path: &Path, bytes: &[u8]) -> Result<BTreeMap<String, NpyArray>> {
    use std::io::Read;
    let file = std::io::Cursor::new(bytes);
    let zerr = |e: zip::result::ZipError| {
        Error::format(
            path,
            "zip archive",
            "a readable .npz (zip) file",
            e.to_string(),
        )
    };
    let mut zip = zip::ZipArchive::new(file).map_err(zerr)?;
    let mut out = BTreeMap::new();
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(zerr)?;
        let name = entry.name().to_string();
        let Some(key) = name.strip_suffix(".npy") else {
            continue;
        };
        let field = format!("entry {name}");
        let max = crate::io::limits::max_decoded_bytes();
        crate::io::limits::check_decoded(path, &field, entry.size())?;
        let mut buf = Vec::with_capacity((entry.size() as usize).min(1 << 28));
        // The declared size may lie: stop reading one byte past the limit.
        (&mut entry)
            .take(max + 1)
            .read_to_end(&mut buf)
            .map_err(|e| Error::format(path, &field, "readable data", e.to_string()))?;
        crate::io::limits::check_decoded(path, &field, buf.len() as u64)?;
        let entry_path = path.join(&name);
        out.insert(key.to_string(), parse_npy(&entry_path, &buf)?);
    }
    if out.is_empty() {
        return Err(Error::format(
            path,
            "entries",
            "at least one .npy entry",
            "none",
        ));
    }
    Ok(out)
}

fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let mut dict = format!(
        "{{'descr': '{descr}', 'fortran_order': False, 'shape': {}, }}",
        shape_str(shape)
    );
    // NumPy pads so the data starts on a 64-byte boundary, header ending with '\n'.
    let total = 10 + dict.len() + 1;
    dict.extend(std::iter::repeat_n(' ', (64 - total % 64) % 64));
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// Encode a C-order little-endian float32 array as NPY v1 bytes (for files or `.npz` entries).
pub fn encode_npy_f32(shape: &[usize], data: &[f32]) -> Vec<u8> {
    let mut out = npy_header("<f4", shape);
    out.reserve(data.len() * 4);
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Encode a C-order little-endian float64 array as NPY v1 bytes (an `.npz` entry, say).
pub fn encode_npy_f64(shape: &[usize], data: &[f64]) -> Vec<u8> {
    let mut out = npy_header("<f8", shape);
    out.reserve(data.len() * 8);
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// An `.npz` archive (a zip, entries deflated) of `(entry name, bytes)`: `name.npy` entries
/// from [`encode_npy_f32`] / [`encode_npy_f64`], and any other member (e.g. `meta.json`, which
/// NumPy's `np.load(..)["meta.json"]` returns as bytes and [`read_npz`] skips).
pub fn encode_npz(entries: &[(String, Vec<u8>)]) -> Result<Vec<u8>> {
    use std::io::Write;
    let zerr = |e: &dyn std::fmt::Display| Error::Encode(format!("encoding an .npz: {e}"));
    let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(entries.iter().any(|(_, b)| b.len() >= u32::MAX as usize));
    // cgenreg's marker: an output guard replaces an archive only when it carries it
    w.set_comment(crate::io::output::NPZ_MARKER);
    for (name, bytes) in entries {
        w.start_file(name.as_str(), opts).map_err(|e| zerr(&e))?;
        w.write_all(bytes).map_err(|e| zerr(&e))?;
    }
    Ok(w.finish().map_err(|e| zerr(&e))?.into_inner())
}

/// Write [`encode_npz`] of `entries` to `path` atomically (temporary file, then rename).
pub fn write_npz(path: &Path, entries: &[(String, Vec<u8>)]) -> Result<()> {
    write_atomic(path, &encode_npz(entries)?)
}

/// A float32 matrix from NPY bytes: a 2-D array as (rows, cols, data), a 1-D array as
/// (n, 1, data); any other rank, or a float64 array, is an error naming `path`. Reads what
/// [`encode_npy_f32`] writes (the stage cache's `.npy` payloads).
pub fn parse_npy_f32_matrix(path: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<f32>)> {
    let a = parse_npy(path, bytes)?;
    let (rows, cols) = match a.shape[..] {
        [n] => (n, 1),
        [r, c] => (r, c),
        _ => {
            return Err(Error::format(
                path,
                "shape",
                "1-D or 2-D",
                shape_str(&a.shape),
            ))
        }
    };
    match a.data {
        NpyData::F32(data) => Ok((rows, cols, data)),
        NpyData::F64(_) => Err(Error::format(path, "dtype", "float32", "float64")),
    }
}

/// Write a C-order little-endian float32 array (NPY v1), atomically.
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    let n: usize = shape.iter().product();
    if n != data.len() {
        return Err(Error::Shape(format!(
            "writing {}: shape {} needs {n} values, got {}",
            path.display(),
            shape_str(shape),
            data.len()
        )));
    }
    write_atomic(path, &encode_npy_f32(shape, data))
}

/// An (N,3) array as a cloud (validated: non-empty, finite).
pub fn array_to_cloud(path: &Path, field: &str, a: &NpyArray) -> Result<PointCloud> {
    if !matches!(a.shape[..], [_, 3]) {
        return Err(Error::format(
            path,
            format!("{field} shape"),
            "(N, 3)",
            shape_str(&a.shape),
        ));
    }
    let pts: Vec<Point3<f32>> = match &a.data {
        NpyData::F32(v) => v
            .chunks_exact(3)
            .map(|c| Point3::new(c[0], c[1], c[2]))
            .collect(),
        NpyData::F64(v) => v
            .chunks_exact(3)
            .map(|c| Point3::new(c[0] as f32, c[1] as f32, c[2] as f32))
            .collect(),
    };
    let cloud = PointCloud::from_points(pts);
    validate_cloud(path, &cloud)?;
    Ok(cloud)
}

pub fn read_npy_points(path: &Path) -> Result<PointCloud> {
    array_to_cloud(path, "array", &read_npy(path)?)
}

/// A (4,4) rigid transform, `p' = M * p`.
pub fn read_npy_matrix4(path: &Path) -> Result<Isometry3<f64>> {
    let a = read_npy(path)?;
    if a.shape != [4, 4] {
        return Err(Error::format(path, "shape", "(4, 4)", shape_str(&a.shape)));
    }
    let m = Matrix4::from_row_slice(&a.to_f64());
    isometry_from_matrix(&m).ok_or_else(|| {
        Error::format(
            path,
            "matrix",
            "a rigid transform (rotation block, bottom row 0 0 0 1)",
            crate::geometry::transform::rigidity_problem(&m),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy_bytes(descr: &str, fortran: bool, shape: &[usize], major: u8, data: &[u8]) -> Vec<u8> {
        let dict = format!(
            "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {}, }}\n",
            if fortran { "True" } else { "False" },
            shape_str(shape)
        );
        let mut b = vec![0x93, b'N', b'U', b'M', b'P', b'Y', major, 0];
        if major == 1 {
            b.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        } else {
            b.extend_from_slice(&(dict.len() as u32).to_le_bytes());
        }
        b.extend_from_slice(dict.as_bytes());
        b.extend_from_slice(data);
        b
    }

    #[test]
    fn dtypes_orders_and_versions() {
        // 2x3 matrix [[0,1,2],[3,4,5]].
        let c_order: [f64; 6] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let f_order: [f64; 6] = [0.0, 3.0, 1.0, 4.0, 2.0, 5.0];
        for major in [1u8, 2, 3] {
            for fortran in [false, true] {
                let vals = if fortran { f_order } else { c_order };
                for descr in ["<f4", ">f4", "<f8", ">f8"] {
                    let mut raw = Vec::new();
                    for v in vals {
                        match descr {
                            "<f4" => raw.extend_from_slice(&(v as f32).to_le_bytes()),
                            ">f4" => raw.extend_from_slice(&(v as f32).to_be_bytes()),
                            "<f8" => raw.extend_from_slice(&v.to_le_bytes()),
                            _ => raw.extend_from_slice(&v.to_be_bytes()),
                        }
                    }
                    let b = npy_bytes(descr, fortran, &[2, 3], major, &raw);
                    let a = parse_npy(Path::new("t.npy"), &b).unwrap();
                    assert_eq!(a.shape, vec![2, 3]);
                    assert_eq!(a.to_f64(), c_order.to_vec(), "{descr} {fortran} v{major}");
                    assert_eq!(
                        a.dtype_name(),
                        if descr.ends_with('4') {
                            "float32"
                        } else {
                            "float64"
                        }
                    );
                }
            }
        }
    }

    #[test]
    fn fortran_3d_reorders() {
        let shape = [2, 3, 4];
        // Value = 100 i + 10 j + k, written first-index-fastest.
        let mut raw = Vec::new();
        for k in 0..4 {
            for j in 0..3 {
                for i in 0..2 {
                    raw.extend_from_slice(&((100 * i + 10 * j + k) as f64).to_le_bytes());
                }
            }
        }
        let a = parse_npy(Path::new("f"), &npy_bytes("<f8", true, &shape, 1, &raw)).unwrap();
        let v = a.to_f64();
        assert_eq!(v[0], 0.0);
        assert_eq!(v[1], 1.0);
        assert_eq!(v[4], 10.0);
        assert_eq!(v[12], 100.0);
        assert_eq!(v[23], 123.0);
    }

    #[test]
    fn write_read_round_trip_and_npz() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        let data: Vec<f32> = (0..30).map(|i| i as f32 * 0.37 - 3.0).collect();
        write_npy_f32(&p, &[10, 3], &data).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let a = read_npy(&p).unwrap();
        assert_eq!(a.shape, vec![10, 3]);
        assert_eq!(a.data, NpyData::F32(data.clone()));
        assert_eq!(read_npy_points(&p).unwrap().len(), 10);
        assert!(write_npy_f32(&p, &[4, 3], &data).is_err());

        // An .npz with one stored and one deflated entry.
        let z = dir.path().join("b.npz");
        {
            use std::io::Write;
            let f = std::fs::File::create(&z).unwrap();
            let mut w = zip::ZipWriter::new(f);
            let stored = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Stored);
            let deflated = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Deflated);
            w.start_file("points.npy", stored).unwrap();
            w.write_all(&bytes).unwrap();
            w.start_file("feats.npy", deflated).unwrap();
            w.write_all(&npy_bytes("<f8", false, &[2], 1, &[0u8; 16]))
                .unwrap();
            w.finish().unwrap();
        }
        let m = read_npz(&z).unwrap();
        assert_eq!(m.keys().collect::<Vec<_>>(), ["feats", "points"]);
        assert_eq!(m["points"], a);
        assert_eq!(m["feats"].to_f64(), vec![0.0, 0.0]);
    }

    #[test]
    fn f32_matrix_round_trip() {
        let p = Path::new("m.npy");
        let (seed, mut rng) = crate::estimate::rng::seeded_for_test("npy-f32-matrix");
        for (rows, cols) in [(0usize, 3usize), (1, 1), (2, 3), (17, 33), (1000, 1)] {
            let data: Vec<f32> = (0..rows * cols)
                .map(|_| f32::from_bits(rng.next_u32()))
                .filter(|v| !v.is_nan())
                .chain(std::iter::repeat(0.0))
                .take(rows * cols)
                .collect();
            let b = encode_npy_f32(&[rows, cols], &data);
            let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
            assert_eq!((10 + hlen) % 64, 0);
            assert_eq!(b[10 + hlen - 1], b'\n');
            let (r, c, d) = parse_npy_f32_matrix(p, &b).unwrap();
            assert_eq!((r, c), (rows, cols), "seed {seed}");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&d), bits(&data), "seed {seed}");
        }
        // 1-D reads as one column.
        let b = encode_npy_f32(&[4], &[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(
            parse_npy_f32_matrix(p, &b).unwrap(),
            (4, 1, vec![1.0, 2.0, 3.0, 4.0])
        );
        // Other ranks, float64 and truncation are errors.
        let e = parse_npy_f32_matrix(p, &encode_npy_f32(&[1, 2, 2], &[0.0; 4])).unwrap_err();
        assert!(e.to_string().contains("shape"), "{e}");
        let f8 = npy_bytes("<f8", false, &[2, 1], 1, &[0u8; 16]);
        let e = parse_npy_f32_matrix(p, &f8).unwrap_err();
        assert!(e.to_string().contains("float32"), "{e}");
        let b = encode_npy_f32(&[3, 2], &[0.0; 6]);
        assert!(parse_npy_f32_matrix(p, &b[..b.len() - 1]).is_err());
    }

    #[test]
    fn malformed() {
        let p = Path::new("bad.npy");
        let ok = npy_bytes("<f4", false, &[2, 3], 1, &[0u8; 24]);
        let e = parse_npy(p, &ok[..ok.len() - 1]).unwrap_err().to_string();
        assert!(e.contains("bad.npy") && e.contains("truncated"), "{e}");
        let e = parse_npy(p, b"\x93NUMPX\x01\x00\x00\x00")
            .unwrap_err()
            .to_string();
        assert!(e.contains("magic"), "{e}");
        let e = parse_npy(p, &npy_bytes("<i4", false, &[2], 1, &[0u8; 8]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("dtype"), "{e}");
        let b = npy_bytes(
            "<f4",
            false,
            &[1, 3],
            1,
            &[0, 0, 0xc0, 0x7f, 0, 0, 0, 0, 0, 0, 0, 0],
        );
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("nan.npy");
        std::fs::write(&f, &b).unwrap();
        let e = read_npy_points(&f).unwrap_err().to_string();
        assert!(e.contains("point 0"), "{e}");
    }

    #[test]
    fn staged_geotransformer_demo() {
        let Some(root) = crate::testing::test_data_root() else {
            return;
        };
        let d = root.join("3dmatch-redkitchen/geotransformer-demo");
        assert_eq!(read_npy_points(&d.join("ref.npy")).unwrap().len(), 18_977);
        assert_eq!(read_npy_points(&d.join("src.npy")).unwrap().len(), 15_953);
        let gt = read_npy_matrix4(&d.join("gt.npy")).unwrap();
        let raw = read_npy(&d.join("gt.npy")).unwrap();
        let log = crate::io::gtlog::read_gt_log(
            &root.join("3dmatch-redkitchen/benchmark/3DMatch/gt.log"),
        )
        .unwrap();
        let e = log.iter().find(|e| e.target == 0 && e.source == 6).unwrap();
        let diff = (gt.to_homogeneous() - e.target_from_source.to_homogeneous()).amax();
        assert!(diff < 1e-9, "gt.npy vs gt.log 0 6: {diff}");
        // The manifest says the matrices are bit-identical to the text of gt.log `0 6`.
        let text =
            std::fs::read_to_string(root.join("3dmatch-redkitchen/benchmark/3DMatch/gt.log"))
                .unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let h = lines
            .iter()
            .position(|l| l.split_whitespace().take(2).eq(["0", "6"]))
            .unwrap();
        let logm: Vec<f64> = lines[h + 1..h + 5]
            .iter()
            .flat_map(|l| l.split_whitespace().map(|t| t.parse::<f64>().unwrap()))
            .collect();
        assert_eq!(raw.to_f64(), logm);
    }
}
