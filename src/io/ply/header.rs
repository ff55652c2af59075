//! The PLY header: elements, their properties and scalar types, and where the vertex
//! attributes sit (what the readers in `mod.rs` walk the body by).

use crate::error::{Error, Result};
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    pub(super) fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    pub(super) fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Decode one value; `b` holds at least `self.size()` bytes.
    #[inline(always)]
    pub(super) fn read(self, b: &[u8], big: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                (if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f64
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => num!(i16, 2),
            Scalar::U16 => num!(u16, 2),
            Scalar::I32 => num!(i32, 4),
            Scalar::U32 => num!(u32, 4),
            Scalar::F32 => num!(f32, 4),
            Scalar::F64 => num!(f64, 8),
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub(super) enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
pub(super) struct Property {
    pub(super) name: String,
    pub(super) kind: Kind,
}

#[derive(Clone, Debug)]
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: usize,
    pub(super) props: Vec<Property>,
}

impl Element {
    /// Bytes per instance when it has no list property.
    pub(super) fn fixed_stride(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

pub(super) struct Header {
    pub(super) format: Format,
    pub(super) elements: Vec<Element>,
    pub(super) body_start: usize,
}

pub(super) fn parse_header(path: &Path, data: &[u8]) -> Result<Header> {
    let magic_ok = data.starts_with(b"ply\n") || data.starts_with(b"ply\r\n");
    if !magic_ok {
        return Err(Error::format(
            path,
            "magic",
            "a file starting with \"ply\"",
            format!(
                "another kind of file ({} bytes; content not shown)",
                data.len()
            ),
        ));
    }
    let mut pos = 0usize;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 0usize;
    loop {
        let Some(nl) = data[pos..].iter().position(|&c| c == b'\n') else {
            return Err(Error::format(
                path,
                "header",
                "an \"end_header\" line",
                "end of file inside the header",
            ));
        };
        let raw = &data[pos..pos + nl];
        pos += nl + 1;
        line_no += 1;
        let line = String::from_utf8_lossy(raw);
        let toks: Vec<&str> = line.split_whitespace().collect();
        let field = || format!("header line {line_no}");
        match toks.first().copied() {
            None | Some("ply") | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                if toks.len() != 3 || toks[2] != "1.0" {
                    return Err(Error::format(
                        path,
                        field(),
                        "format <ascii | binary_little_endian | binary_big_endian> 1.0",
                        format!("{line:?}"),
                    ));
                }
                format = Some(match toks.get(1).copied() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLe,
                    Some("binary_big_endian") => Format::BinaryBe,
                    other => {
                        return Err(Error::format(
                            path,
                            field(),
                            "format ascii | binary_little_endian | binary_big_endian",
                            crate::io::output::unquoted(other.unwrap_or("")),
                        ))
                    }
                });
            }
            Some("element") => {
                let count = toks.get(2).and_then(|c| c.parse::<usize>().ok());
                match (toks.get(1), count) {
                    (Some(name), Some(count)) if toks.len() == 3 => elements.push(Element {
                        name: name.to_string(),
                        count,
                        props: Vec::new(),
                    }),
                    _ => {
                        return Err(Error::format(
                            path,
                            field(),
                            "element <name> <count>",
                            crate::io::output::unquoted(&line),
                        ))
                    }
                }
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(Error::format(
                        path,
                        field(),
                        "a property after an element line",
                        crate::io::output::unquoted(&line),
                    ));
                };
                let prop = if toks.get(1) == Some(&"list") {
                    let c = toks.get(2).and_then(|t| Scalar::parse(t));
                    let i = toks.get(3).and_then(|t| Scalar::parse(t));
                    match (c, i, toks.get(4)) {
                        (Some(count), Some(item), Some(name)) if !count.is_float() => Property {
                            name: name.to_string(),
                            kind: Kind::List { count, item },
                        },
                        _ => {
                            return Err(Error::format(
                                path,
                                field(),
                                "property list <int type> <type> <name>",
                                crate::io::output::unquoted(&line),
                            ))
                        }
                    }
                } else {
                    match (toks.get(1).and_then(|t| Scalar::parse(t)), toks.get(2)) {
                        (Some(s), Some(name)) => Property {
                            name: name.to_string(),
                            kind: Kind::Scalar(s),
                        },
                        _ => {
                            return Err(Error::format(
                                path,
                                field(),
                                "property <type> <name> with a known type",
                                crate::io::output::unquoted(&line),
                            ))
                        }
                    }
                };
                el.props.push(prop);
            }
            Some("end_header") => break,
            Some(other) => {
                return Err(Error::format(
                    path,
                    field(),
                    "format, element, property, comment, obj_info or end_header",
                    format!("{other:?}"),
                ))
            }
        }
    }
    let Some(format) = format else {
        return Err(Error::format(
            path,
            "format",
            "a format line",
            "none in the header",
        ));
    };
    Ok(Header {
        format,
        elements,
        body_start: pos,
    })
}

/// Where each recognised attribute sits in a vertex: (property index) per role.
#[derive(Default)]
pub(super) struct Roles {
    pub(super) xyz: [Option<usize>; 3],
    pub(super) rgb: [Option<usize>; 3],
    pub(super) normal: [Option<usize>; 3],
    pub(super) intensity: Option<usize>,
}

pub(super) fn roles(path: &Path, el: &Element) -> Result<Roles> {
    let mut r = Roles::default();
    for (i, p) in el.props.iter().enumerate() {
        let slot = match p.name.as_str() {
            "x" => &mut r.xyz[0],
            "y" => &mut r.xyz[1],
            "z" => &mut r.xyz[2],
            "red" | "r" | "diffuse_red" => &mut r.rgb[0],
            "green" | "g" | "diffuse_green" => &mut r.rgb[1],
            "blue" | "b" | "diffuse_blue" => &mut r.rgb[2],
            "nx" | "normal_x" => &mut r.normal[0],
            "ny" | "normal_y" => &mut r.normal[1],
            "nz" | "normal_z" => &mut r.normal[2],
            "intensity" | "scalar_intensity" => &mut r.intensity,
            _ => continue,
        };
        if matches!(p.kind, Kind::List { .. }) {
            return Err(Error::format(
                path,
                format!("vertex property {}", p.name),
                "a scalar property",
                "a list property",
            ));
        }
        *slot = Some(i);
    }
    if r.xyz.iter().any(Option::is_none) {
        let names: Vec<&str> = el.props.iter().map(|p| p.name.as_str()).collect();
        return Err(Error::format(
            path,
            "vertex properties",
            "x, y and z",
            names.join(" "),
        ));
    }
    Ok(r)
}
