//! A minimal, safe Python pickle reader for NumPy arrays.
//!
//! Supports the opcodes of protocols 0-5 that plain data uses (ints, floats, strings, bytes,
//! tuples, lists, dicts, sets, memo), plus exactly the globals NumPy needs to rebuild a
//! float array: `numpy.(_)core.multiarray._reconstruct`, `numpy.ndarray`, `numpy.dtype`,
//! `numpy.(_)core.numeric._frombuffer` (protocol 5), `_codecs.encode` (protocol 2 bytes) and
//! `collections.OrderedDict`. Any other global is refused: nothing is ever executed.
//!
//! Two file shapes are read:
//! - a pickled dict of float arrays (the GeoTransformer feature `.pkl` files of the C-GenReg
//!   reference: `ref_points_f (Nr,3)`, `ref_feats_f (Nr,256)`, `src_points_f`, `src_feats_f`);
//! - a legacy (non-zip) PyTorch `torch.save` of a NumPy array (Predator / RegTR `.pth`):
//!   5 concatenated pickles (magic number, protocol version 1001, sys info, the object,
//!   storage keys); the 4th is the array. Torch tensors (persistent storages) are refused.
//!
//! Array values keep their dtype (float32 / float64) and are returned in C order; clouds are
//! (N,3) x,y,z in metres.

use super::npy::{array_to_cloud, decode_array, parse_descr, shape_str, NpyArray};
use crate::error::{Error, Result};
use crate::geometry::cloud::PointCloud;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::rc::Rc;

/// `torch.save`'s legacy magic number, the first pickle of a `.pth` file.
const TORCH_MAGIC: i128 = 0x1950a86a20f9469cfc6c;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Global {
    Reconstruct,
    NdArray,
    Dtype,
    CodecsEncode,
    FromBuffer,
    OrderedDict,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Dtype {
    kind: char,
    size: usize,
    big: bool,
}

#[derive(Clone, Debug)]
struct PyArray {
    dtype: Option<Dtype>,
    shape: Vec<usize>,
    fortran: bool,
    data: Option<Rc<Vec<u8>>>,
}

#[derive(Clone, Debug)]
enum Value {
    None,
    Bool(bool),
    Int(i128),
    Float(#[allow(dead_code)] f64),
    Str(Rc<str>),
    /// A long str whose chars are all <= U+00FF, kept as its latin-1 bytes (protocol-2
    /// array data); decoding it this way skips a slow general UTF-8 pass.
    Latin1(Rc<Vec<u8>>),
    Bytes(Rc<Vec<u8>>),
    // Containers carry an identity (for the memo and for their nesting depth).
    Tuple(u64, Vec<Value>),
    // Mutable objects carry an identity so the memo can follow later mutations.
    List(u64, Vec<Value>),
    Dict(u64, Vec<(Value, Value)>),
    Array(u64, PyArray),
    Dtype(u64, Dtype),
    Global(Global),
}

impl Value {
    fn id(&self) -> Option<u64> {
        match self {
            Value::List(id, _) | Value::Dict(id, _) | Value::Array(id, _) | Value::Dtype(id, _) => {
                Some(*id)
            }
            // Tuples are immutable: no memo refresh needed.
            Value::Tuple(..) => None,
            _ => None,
        }
    }
    fn type_name(&self) -> &'static str {
        match self {
            Value::None => "None",
            Value::Bool(_) => "bool",
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::Str(_) | Value::Latin1(_) => "str",
            Value::Bytes(_) => "bytes",
            Value::Tuple(..) => "tuple",
            Value::List(..) => "list",
            Value::Dict(..) => "dict",
            Value::Array(..) => "numpy.ndarray",
            Value::Dtype(..) => "numpy.dtype",
            Value::Global(_) => "global",
        }
    }
    fn as_shape(&self) -> Option<Vec<usize>> {
        match self {
            Value::Tuple(_, v) | Value::List(_, v) => v
                .iter()
                .map(|d| match d {
                    Value::Int(n) if *n >= 0 => usize::try_from(*n).ok(),
                    _ => None,
                })
                .collect(),
            _ => None,
        }
    }
    /// Raw bytes of a bytes value, or of a str that holds bytes as latin-1 (Python 2 data).
    fn as_raw_bytes(&self) -> Option<Rc<Vec<u8>>> {
        match self {
            Value::Bytes(b) | Value::Latin1(b) => Some(b.clone()),
            Value::Str(s) => latin1(s.as_bytes()).map(Rc::new),
            _ => None,
        }
    }
}

/// Encode UTF-8 text as latin-1, or None if it is not valid UTF-8 made only of chars
/// <= U+00FF (1 byte, or 0xC2/0xC3 followed by a continuation byte).
fn latin1(b: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c < 0x80 {
            out.push(c);
            i += 1;
        } else if (c == 0xC2 || c == 0xC3) && i + 1 < b.len() && b[i + 1] & 0xC0 == 0x80 {
            out.push(((c & 0x03) << 6) | (b[i + 1] & 0x3f));
            i += 2;
        } else {
            return None;
        }
    }
    Some(out)
}

enum Decoded {
    /// Every char is <= U+00FF: kept as latin-1 bytes.
    Latin1(Vec<u8>),
    Text(String),
}

/// Decode Python's `raw-unicode-escape`: each byte is the char of that code, except
/// `\uXXXX` and `\UXXXXXXXX` (an odd run of backslashes before `u`/`U` starts an escape).
fn raw_unicode_escape(b: &[u8]) -> Option<Decoded> {
    let mut chars: Vec<u32> = Vec::with_capacity(b.len());
    let mut i = 0;
    let mut slashes = 0usize;
    while i < b.len() {
        let c = b[i];
        if c == b'\\' {
            slashes += 1;
        } else if (c == b'u' || c == b'U') && slashes % 2 == 1 {
            let n = if c == b'u' { 4 } else { 8 };
            let hex = std::str::from_utf8(b.get(i + 1..i + 1 + n)?).ok()?;
            if !hex.bytes().all(|h| h.is_ascii_hexdigit()) {
                return None;
            }
            let code = u32::from_str_radix(hex, 16).ok()?;
            char::from_u32(code)?;
            chars.pop(); // the backslash that started the escape
            chars.push(code);
            slashes = 0;
            i += 1 + n;
            continue;
        } else {
            slashes = 0;
        }
        chars.push(c as u32);
        i += 1;
    }
    if chars.iter().all(|&c| c <= 0xff) {
        Some(Decoded::Latin1(
            chars.into_iter().map(|c| c as u8).collect(),
        ))
    } else {
        Some(Decoded::Text(
            chars.into_iter().filter_map(char::from_u32).collect(),
        ))
    }
}

struct Vm<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
    /// Which pickle of the file (0-based), for error messages.
    index: usize,
    stack: Vec<Value>,
    marks: Vec<usize>,
    memo: HashMap<u32, Value>,
    memo_of: HashMap<u64, Vec<u32>>,
    next_id: u64,
    /// Nesting depth of every container built so far (by identity), and the limit: deep
    /// nesting would overflow the stack when the values are cloned, printed or dropped.
    /// Also their size in values: memo gets and DUP copy values (Python shares them), so a
    /// list appended to itself would double each time without a cap.
    depth: HashMap<u64, (usize, u64)>,
    max_depth: usize,
    max_values: u64,
    /// Values copied so far by memo gets and DUP, capped by `max_values` too.
    copied: u64,
}

impl<'a> Vm<'a> {
    fn new(path: &'a Path, data: &'a [u8]) -> Self {
        Vm {
            path,
            data,
            pos: 0,
            index: 0,
            stack: Vec::new(),
            marks: Vec::new(),
            memo: HashMap::new(),
            memo_of: HashMap::new(),
            next_id: 0,
            depth: HashMap::new(),
            max_depth: crate::io::limits::max_nesting(),
            max_values: 1_000_000 + 64 * data.len() as u64,
            copied: 0,
        }
    }

    fn err(&self, expected: impl Into<String>, found: impl Into<String>) -> Error {
        Error::format(
            self.path,
            format!("pickle {} at byte {}", self.index, self.pos),
            expected,
            found,
        )
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        match end {
            Some(e) => {
                let s = &self.data[self.pos..e];
                self.pos = e;
                Ok(s)
            }
            None => Err(self.err(
                format!("{n} more bytes (file truncated?)"),
                format!("{} bytes left", self.data.len() - self.pos),
            )),
        }
    }
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Result<usize> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        usize::try_from(u64::from_le_bytes(a)).map_err(|_| self.err("a sane length", "too large"))
    }
    fn line(&mut self) -> Result<&'a str> {
        let rest = &self.data[self.pos..];
        let nl = rest
            .iter()
            .position(|&c| c == b'\n')
            .ok_or_else(|| self.err("a newline-terminated argument", "end of file"))?;
        let s = std::str::from_utf8(&rest[..nl])
            .map_err(|_| self.err("an ASCII argument", "invalid UTF-8"))?;
        self.pos += nl + 1;
        Ok(s.trim_end_matches('\r'))
    }
    /// (nesting depth, number of values) of `v`.
    fn weight(&self, v: &Value) -> (usize, u64) {
        match v {
            Value::Tuple(id, _) | Value::List(id, _) | Value::Dict(id, _) => {
                self.depth.get(id).copied().unwrap_or((1, 1))
            }
            _ => (0, 1),
        }
    }
    /// A new container holding `items`: its identity, after checking the nesting limit.
    fn container(&mut self, items: &[Value]) -> Result<u64> {
        let refs: Vec<&Value> = items.iter().collect();
        self.container_of(&refs)
    }
    fn container_of(&mut self, items: &[&Value]) -> Result<u64> {
        let id = self.new_id();
        self.depth.insert(id, (1, 1));
        self.grow_of(id, items)?;
        Ok(id)
    }
    /// Container `id` receives `items`: raise its depth, failing past the limit.
    fn grow(&mut self, id: u64, items: &[Value]) -> Result<()> {
        let refs: Vec<&Value> = items.iter().collect();
        self.grow_of(id, &refs)
    }
    fn grow_of(&mut self, id: u64, items: &[&Value]) -> Result<()> {
        let (d0, n0) = self.depth.get(&id).copied().unwrap_or((1, 1));
        let (mut d, mut n) = (d0, n0);
        for v in items {
            let (dv, nv) = self.weight(v);
            d = d.max(dv + 1);
            n = n.saturating_add(nv);
        }
        if n > self.max_values {
            return Err(self.err(
                format!(
                    "at most {} values in one object (copies through the memo count)",
                    self.max_values
                ),
                format!("{n} values"),
            ));
        }
        if d > self.max_depth {
            return Err(self.err(
                format!(
                    "containers nested at most {} levels deep (raise {} if the data is real)",
                    self.max_depth,
                    crate::io::limits::ENV_MAX_NESTING
                ),
                format!("{d} levels"),
            ));
        }
        self.depth.insert(id, (d, n));
        Ok(())
    }
    fn count_copy(&mut self, v: &Value) -> Result<()> {
        self.copied = self.copied.saturating_add(self.weight(v).1);
        if self.copied > self.max_values {
            return Err(self.err(
                format!("at most {} values copied by memo gets", self.max_values),
                format!("{} values", self.copied),
            ));
        }
        Ok(())
    }
    fn new_id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id
    }
    fn pop(&mut self) -> Result<Value> {
        if self.marks.last() == Some(&self.stack.len()) {
            return Err(self.err("a value on the stack", "a mark"));
        }
        self.stack
            .pop()
            .ok_or_else(|| self.err("a value on the stack", "an empty stack"))
    }
    fn pop_mark(&mut self) -> Result<Vec<Value>> {
        let m = self
            .marks
            .pop()
            .ok_or_else(|| self.err("a mark on the stack", "none"))?;
        Ok(self.stack.split_off(m))
    }
    fn top(&mut self) -> Result<&mut Value> {
        if self.marks.last() == Some(&self.stack.len()) {
            return Err(self.err("a value on the stack", "a mark"));
        }
        let pos = self.pos;
        let index = self.index;
        let path = self.path;
        self.stack.last_mut().ok_or_else(|| {
            Error::format(
                path,
                format!("pickle {index} at byte {pos}"),
                "a value on the stack",
                "an empty stack",
            )
        })
    }
    fn put(&mut self, key: u32) -> Result<()> {
        let v = self.top()?.clone();
        if let Some(id) = v.id() {
            self.memo_of.entry(id).or_default().push(key);
        }
        self.memo.insert(key, v);
        Ok(())
    }
    fn get(&mut self, key: u32) -> Result<()> {
        let v = self
            .memo
            .get(&key)
            .cloned()
            .ok_or_else(|| self.err("a memo key that was stored", format!("key {key}")))?;
        self.count_copy(&v)?;
        self.stack.push(v);
        Ok(())
    }
    /// After the top object was mutated, refresh memo copies of it.
    fn sync_top(&mut self) -> Result<()> {
        let top = self.top()?.clone();
        if let Some(keys) = top.id().and_then(|id| self.memo_of.get(&id)) {
            for k in keys {
                self.memo.insert(*k, top.clone());
            }
        }
        Ok(())
    }
    fn int(&self, v: &[u8]) -> Result<Value> {
        if v.len() > 16 {
            return Err(self.err(
                "an integer of at most 16 bytes",
                format!("{} bytes", v.len()),
            ));
        }
        let mut a = [0u8; 16];
        a[..v.len()].copy_from_slice(v);
        if v.last().is_some_and(|&b| b & 0x80 != 0) {
            a[v.len()..].fill(0xff);
        }
        Ok(Value::Int(i128::from_le_bytes(a)))
    }
    fn str(&self, b: &[u8]) -> Result<Value> {
        std::str::from_utf8(b)
            .map(|s| Value::Str(Rc::from(s)))
            .map_err(|_| self.err("UTF-8 text", "invalid UTF-8"))
    }

    fn global(&self, module: &str, name: &str) -> Result<Global> {
        Ok(match (module, name) {
            ("numpy.core.multiarray" | "numpy._core.multiarray", "_reconstruct") => {
                Global::Reconstruct
            }
            ("numpy", "ndarray") => Global::NdArray,
            ("numpy", "dtype") => Global::Dtype,
            ("_codecs", "encode") => Global::CodecsEncode,
            ("numpy.core.numeric" | "numpy._core.numeric", "_frombuffer") => Global::FromBuffer,
            ("collections", "OrderedDict") => Global::OrderedDict,
            _ => {
                return Err(self.err(
                    "only the NumPy array reconstruction globals (nothing else is executed)",
                    format!("global {module}.{name}"),
                ))
            }
        })
    }

    fn call(&mut self, f: Value, args: Value) -> Result<Value> {
        let Value::Global(g) = f else {
            return Err(self.err("a callable global", f.type_name()));
        };
        let Value::Tuple(_, args) = args else {
            return Err(self.err("an argument tuple", args.type_name()));
        };
        let bad = |vm: &Self, what: &str| {
            vm.err(
                what.to_string(),
                format!("{args:?}").chars().take(120).collect::<String>(),
            )
        };
        match g {
            Global::Reconstruct => match args.first() {
                Some(Value::Global(Global::NdArray)) => Ok(Value::Array(
                    self.new_id(),
                    PyArray {
                        dtype: None,
                        shape: vec![0],
                        fortran: false,
                        data: None,
                    },
                )),
                _ => Err(bad(self, "_reconstruct(numpy.ndarray, shape, dtype)")),
            },
            Global::CodecsEncode => match &args[..] {
                [Value::Latin1(b), Value::Str(enc)]
                    if matches!(
                        enc.to_ascii_lowercase().as_str(),
                        "latin1" | "latin-1" | "iso-8859-1"
                    ) =>
                {
                    Ok(Value::Bytes(b.clone()))
                }
                [Value::Str(s), Value::Str(enc)]
                    if matches!(
                        enc.to_ascii_lowercase().as_str(),
                        "latin1" | "latin-1" | "iso-8859-1"
                    ) =>
                {
                    let b = latin1(s.as_bytes())
                        .ok_or_else(|| self.err("latin-1 text", "a character above U+00FF"))?;
                    Ok(Value::Bytes(Rc::new(b)))
                }
                _ => Err(bad(self, "_codecs.encode(str, 'latin1')")),
            },
            Global::Dtype => match args.first() {
                Some(Value::Str(d)) => {
                    let (kind, size, big) = parse_descr(d)
                        .ok_or_else(|| self.err("a dtype string like 'f4'", format!("{d:?}")))?;
                    Ok(Value::Dtype(self.new_id(), Dtype { kind, size, big }))
                }
                _ => Err(bad(self, "numpy.dtype(str, ...)")),
            },
            Global::FromBuffer => match &args[..] {
                [buf, Value::Dtype(_, dt), shape, order] => {
                    let data = buf
                        .as_raw_bytes()
                        .ok_or_else(|| bad(self, "_frombuffer(bytes, dtype, shape, order)"))?;
                    let shape = shape.as_shape().ok_or_else(|| bad(self, "a shape tuple"))?;
                    let fortran = matches!(order, Value::Str(o) if &**o == "F");
                    Ok(Value::Array(
                        self.new_id(),
                        PyArray {
                            dtype: Some(*dt),
                            shape,
                            fortran,
                            data: Some(data),
                        },
                    ))
                }
                _ => Err(bad(self, "_frombuffer(bytes, dtype, shape, order)")),
            },
            Global::OrderedDict => Ok(Value::Dict(self.container(&[])?, Vec::new())),
            Global::NdArray => Err(self.err(
                "numpy.ndarray built through _reconstruct",
                "a direct numpy.ndarray call",
            )),
        }
    }

    fn build(&mut self, state: Value) -> Result<()> {
        let path = self.path;
        let (index, pos) = (self.index, self.pos);
        let err =
            |e: &str, f: String| Error::format(path, format!("pickle {index} at byte {pos}"), e, f);
        match self.top()? {
            Value::Dtype(_, dt) => {
                // State: (version, byteorder, subarray, names, fields, elsize, alignment, flags).
                if let Value::Tuple(_, s) = &state {
                    match s.get(1) {
                        Some(Value::Str(o)) if &**o == ">" => dt.big = true,
                        Some(Value::Str(o)) if &**o == "<" => dt.big = false,
                        _ => {}
                    }
                    if matches!(s.get(3), Some(Value::Tuple(..))) {
                        return Err(err("a plain float dtype", "a structured dtype".into()));
                    }
                }
            }
            Value::Array(_, a) => {
                // State: (version, shape, dtype, is_fortran, data) or without the version.
                let s = match &state {
                    Value::Tuple(_, s) if s.len() == 5 => &s[1..],
                    Value::Tuple(_, s) if s.len() == 4 => &s[..],
                    other => {
                        return Err(err(
                            "an ndarray state tuple (version, shape, dtype, fortran, data)",
                            other.type_name().into(),
                        ))
                    }
                };
                let shape = s[0]
                    .as_shape()
                    .ok_or_else(|| err("an ndarray shape tuple", s[0].type_name().into()))?;
                let Value::Dtype(_, dt) = &s[1] else {
                    return Err(err("an ndarray dtype", s[1].type_name().into()));
                };
                let fortran = matches!(s[2], Value::Bool(true));
                let data = s[3].as_raw_bytes().ok_or_else(|| {
                    err(
                        "raw array bytes (object arrays are not supported)",
                        s[3].type_name().into(),
                    )
                })?;
                *a = PyArray {
                    dtype: Some(*dt),
                    shape,
                    fortran,
                    data: Some(data),
                };
            }
            // OrderedDict and friends may carry an instance dict state; nothing to keep.
            Value::Dict(..) => {}
            other => {
                return Err(err(
                    "a numpy array or dtype to BUILD",
                    other.type_name().into(),
                ))
            }
        }
        self.sync_top()
    }

    /// Run one pickle from the current position to its STOP.
    fn run(&mut self) -> Result<Value> {
        self.stack.clear();
        self.marks.clear();
        self.memo.clear();
        self.memo_of.clear();
        self.depth.clear();
        loop {
            let op = self.u8()?;
            match op {
                0x80 => {
                    let p = self.u8()?;
                    if p > 5 {
                        return Err(self.err("pickle protocol 0-5", format!("{p}")));
                    }
                }
                0x95 => {
                    self.u64()?;
                }
                b'.' => {
                    let v = self.pop()?;
                    return Ok(v);
                }
                b'(' => self.marks.push(self.stack.len()),
                b'N' => self.stack.push(Value::None),
                0x88 => self.stack.push(Value::Bool(true)),
                0x89 => self.stack.push(Value::Bool(false)),
                b'J' => {
                    let v = self.u32()? as i32;
                    self.stack.push(Value::Int(v as i128));
                }
                b'K' => {
                    let v = self.u8()?;
                    self.stack.push(Value::Int(v as i128));
                }
                b'M' => {
                    let v = self.u16()?;
                    self.stack.push(Value::Int(v as i128));
                }
                0x8a | 0x8b => {
                    let n = if op == 0x8a {
                        self.u8()? as usize
                    } else {
                        self.u32()? as usize
                    };
                    let b = self.take(n)?;
                    let v = self.int(b)?;
                    self.stack.push(v);
                }
                b'I' | b'L' => {
                    let l = self.line()?.trim_end_matches('L');
                    let v = match l {
                        "01" => Value::Bool(true),
                        "00" => Value::Bool(false),
                        _ => Value::Int(
                            l.parse()
                                .map_err(|_| self.err("a decimal integer", format!("{l:?}")))?,
                        ),
                    };
                    self.stack.push(v);
                }
                b'F' => {
                    let l = self.line()?;
                    let v = l
                        .parse()
                        .map_err(|_| self.err("a decimal float", format!("{l:?}")))?;
                    self.stack.push(Value::Float(v));
                }
                b'G' => {
                    let b = self.take(8)?;
                    let mut a = [0u8; 8];
                    a.copy_from_slice(b);
                    self.stack.push(Value::Float(f64::from_be_bytes(a)));
                }
                b'X' | 0x8c | 0x8d => {
                    let n = match op {
                        b'X' => self.u32()? as usize,
                        0x8c => self.u8()? as usize,
                        _ => self.u64()?,
                    };
                    let b = self.take(n)?;
                    let v = match (n > 4096).then(|| latin1(b)).flatten() {
                        Some(l) => Value::Latin1(Rc::new(l)),
                        None => self.str(b)?,
                    };
                    self.stack.push(v);
                }
                // Protocol 0 UNICODE: raw-unicode-escape text up to a newline (bytes are
                // latin-1 chars, `\uXXXX` / `\UXXXXXXXX` escape the rest).
                b'V' => {
                    let rest = &self.data[self.pos..];
                    let nl = rest.iter().position(|&c| c == b'\n').ok_or_else(|| {
                        self.err("a newline-terminated UNICODE argument", "end of file")
                    })?;
                    let v = match raw_unicode_escape(&rest[..nl]) {
                        Some(Decoded::Latin1(b)) if b.len() > 4096 => Value::Latin1(Rc::new(b)),
                        Some(Decoded::Latin1(b)) => {
                            Value::Str(Rc::from(b.iter().map(|&c| c as char).collect::<String>()))
                        }
                        Some(Decoded::Text(t)) => Value::Str(Rc::from(t)),
                        None => {
                            return Err(
                                self.err("raw-unicode-escape text", "a bad \\u or \\U escape")
                            )
                        }
                    };
                    self.pos += nl + 1;
                    self.stack.push(v);
                }
                // Python 2 str: bytes that Python 3 decodes as latin-1.
                b'T' | b'U' => {
                    let n = if op == b'T' {
                        self.u32()? as usize
                    } else {
                        self.u8()? as usize
                    };
                    let b = self.take(n)?;
                    let s: String = b.iter().map(|&c| c as char).collect();
                    self.stack.push(Value::Str(Rc::from(s)));
                }
                b'B' | b'C' | 0x8e | 0x96 => {
                    let n = match op {
                        b'B' => self.u32()? as usize,
                        b'C' => self.u8()? as usize,
                        _ => self.u64()?,
                    };
                    let b = self.take(n)?;
                    self.stack.push(Value::Bytes(Rc::new(b.to_vec())));
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    let g = self.global(module, name)?;
                    self.stack.push(Value::Global(g));
                }
                0x93 => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    let (Value::Str(m), Value::Str(n)) = (&module, &name) else {
                        return Err(self.err("two strings for STACK_GLOBAL", "other values"));
                    };
                    let g = self.global(m, n)?;
                    self.stack.push(Value::Global(g));
                }
                b'q' => {
                    let k = self.u8()? as u32;
                    self.put(k)?;
                }
                b'r' => {
                    let k = self.u32()?;
                    self.put(k)?;
                }
                0x94 => {
                    let k = self.memo.len() as u32;
                    self.put(k)?;
                }
                b'p' => {
                    let l = self.line()?;
                    let k = l
                        .parse()
                        .map_err(|_| self.err("a memo key", format!("{l:?}")))?;
                    self.put(k)?;
                }
                b'h' => {
                    let k = self.u8()? as u32;
                    self.get(k)?;
                }
                b'j' => {
                    let k = self.u32()?;
                    self.get(k)?;
                }
                b'g' => {
                    let l = self.line()?;
                    let k = l
                        .parse()
                        .map_err(|_| self.err("a memo key", format!("{l:?}")))?;
                    self.get(k)?;
                }
                b')' => {
                    let id = self.container(&[])?;
                    self.stack.push(Value::Tuple(id, Vec::new()));
                }
                0x85..=0x87 => {
                    let n = (op - 0x84) as usize;
                    if self.stack.len() < n + self.marks.last().copied().unwrap_or(0) {
                        return Err(self.err(format!("{n} values for a tuple"), "fewer"));
                    }
                    let items = self.stack.split_off(self.stack.len() - n);
                    let id = self.container(&items)?;
                    self.stack.push(Value::Tuple(id, items));
                }
                b't' => {
                    let items = self.pop_mark()?;
                    let id = self.container(&items)?;
                    self.stack.push(Value::Tuple(id, items));
                }
                b']' | 0x8f => {
                    let id = self.container(&[])?;
                    self.stack.push(Value::List(id, Vec::new()));
                }
                b'l' | 0x91 => {
                    let items = self.pop_mark()?;
                    let id = self.container(&items)?;
                    self.stack.push(Value::List(id, items));
                }
                b'a' | b'e' | 0x90 => {
                    let items = if op == b'a' {
                        vec![self.pop()?]
                    } else {
                        self.pop_mark()?
                    };
                    let id = match self.top()? {
                        Value::List(id, _) => *id,
                        other => {
                            let t = other.type_name();
                            return Err(self.err("a list to append to", t));
                        }
                    };
                    self.grow(id, &items)?;
                    match self.top()? {
                        Value::List(_, l) => l.extend(items),
                        other => {
                            let t = other.type_name();
                            return Err(self.err("a list to append to", t));
                        }
                    }
                    self.sync_top()?;
                }
                b'}' => {
                    let id = self.container(&[])?;
                    self.stack.push(Value::Dict(id, Vec::new()));
                }
                b'd' | b's' | b'u' => {
                    let items = match op {
                        b's' => {
                            let v = self.pop()?;
                            let k = self.pop()?;
                            vec![k, v]
                        }
                        _ => self.pop_mark()?,
                    };
                    if items.len() % 2 != 0 {
                        return Err(self.err("key/value pairs", "an odd number of items"));
                    }
                    let mut pairs = Vec::with_capacity(items.len() / 2);
                    let mut it = items.into_iter();
                    while let (Some(k), Some(v)) = (it.next(), it.next()) {
                        pairs.push((k, v));
                    }
                    if op == b'd' {
                        let flat: Vec<&Value> = pairs.iter().flat_map(|(k, v)| [k, v]).collect();
                        let id = self.container_of(&flat)?;
                        self.stack.push(Value::Dict(id, pairs));
                    } else {
                        let id = match self.top()? {
                            Value::Dict(id, _) => *id,
                            other => {
                                let t = other.type_name();
                                return Err(self.err("a dict to set items in", t));
                            }
                        };
                        let flat: Vec<&Value> = pairs.iter().flat_map(|(k, v)| [k, v]).collect();
                        self.grow_of(id, &flat)?;
                        match self.top()? {
                            Value::Dict(_, d) => d.extend(pairs),
                            other => {
                                let t = other.type_name();
                                return Err(self.err("a dict to set items in", t));
                            }
                        }
                        self.sync_top()?;
                    }
                }
                b'0' => {
                    if self.marks.last() == Some(&self.stack.len()) {
                        self.marks.pop();
                    } else {
                        self.pop()?;
                    }
                }
                b'1' => {
                    self.pop_mark()?;
                }
                b'2' => {
                    let v = self.top()?.clone();
                    self.count_copy(&v)?;
                    self.stack.push(v);
                }
                b'R' | 0x81 => {
                    let args = self.pop()?;
                    let f = self.pop()?;
                    let v = self.call(f, args)?;
                    self.stack.push(v);
                }
                b'b' => {
                    let state = self.pop()?;
                    self.build(state)?;
                }
                b'P' | b'Q' => return Err(self.err(
                    "NumPy arrays only",
                    "a persistent id (a torch tensor storage); re-save the data as a NumPy array",
                )),
                0x97 | 0x98 => return Err(self.err("in-band data", "an out-of-band pickle buffer")),
                _ => {
                    return Err(self.err("a supported pickle opcode", format!("opcode 0x{op:02x}")))
                }
            }
        }
    }
}

fn to_npy(path: &Path, field: &str, a: &PyArray) -> Result<NpyArray> {
    match (&a.dtype, &a.data) {
        (Some(dt), Some(data)) => decode_array(
            path,
            field,
            (dt.kind, dt.size, dt.big),
            &a.shape,
            a.fortran,
            data,
        ),
        _ => Err(Error::format(
            path,
            field,
            "an ndarray with its state set",
            "an incomplete ndarray",
        )),
    }
}

/// Parse a pickled dict of arrays; keys must be strings. Float arrays are returned; values
/// that are not float arrays (ints, strings, integer arrays) are skipped.
pub fn parse_pickle_arrays(path: &Path, bytes: &[u8]) -> Result<BTreeMap<String, NpyArray>> {
    let mut vm = Vm::new(path, bytes);
    let v = vm.run()?;
    let Value::Dict(_, items) = v else {
        return Err(Error::format(
            path,
            "pickle",
            "a dict of arrays",
            v.type_name(),
        ));
    };
    let mut out = BTreeMap::new();
    for (k, v) in items {
        let (Value::Str(k), Value::Array(_, a)) = (&k, &v) else {
            continue;
        };
        if a.dtype.is_some_and(|d| d.kind != 'f') {
            continue;
        }
        out.insert(k.to_string(), to_npy(path, k, a)?);
    }
    if out.is_empty() {
        return Err(Error::format(
            path,
            "pickle",
            "a dict with at least one float array",
            "no float arrays",
        ));
    }
    Ok(out)
}

pub fn read_pickle_arrays(path: &Path) -> Result<BTreeMap<String, NpyArray>> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_pickle_arrays(path, &bytes)
}

/// Parse a legacy `torch.save` of a NumPy array (or a plain pickle of one array).
pub fn parse_pth_array(path: &Path, bytes: &[u8]) -> Result<NpyArray> {
    if bytes.starts_with(b"PK\x03\x04") {
        return Err(Error::format(
            path,
            "format",
            "a legacy (non-zip) torch.save of a NumPy array",
            "a zip-based torch.save archive (save a NumPy array with \
             _use_new_zipfile_serialization=False, or export .npy)",
        ));
    }
    let mut vm = Vm::new(path, bytes);
    let first = vm.run()?;
    let obj = match first {
        Value::Int(TORCH_MAGIC) => {
            let mut obj = None;
            for k in 1..5 {
                vm.index = k;
                let v = vm.run()?;
                match k {
                    1 if !matches!(v, Value::Int(1001)) => {
                        return Err(vm.err("torch protocol version 1001", format!("{v:?}")))
                    }
                    3 => obj = Some(v),
                    4 if !matches!(&v, Value::List(_, l) if l.is_empty()) => {
                        return Err(vm.err(
                            "an empty storage list (NumPy data only)",
                            "torch tensor storages",
                        ))
                    }
                    _ => {}
                }
            }
            obj.unwrap_or(Value::None)
        }
        other => other,
    };
    match obj {
        Value::Array(_, a) => to_npy(path, "array", &a),
        other => Err(Error::format(
            path,
            "object",
            "a numpy.ndarray",
            other.type_name(),
        )),
    }
}

pub fn read_pth_array(path: &Path) -> Result<NpyArray> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_pth_array(path, &bytes)
}

/// An (N,3) `.pth` array as a cloud.
pub fn read_pth_points(path: &Path) -> Result<PointCloud> {
    let a = read_pth_array(path)?;
    if !matches!(a.shape[..], [_, 3]) {
        return Err(Error::format(
            path,
            "array shape",
            "(N, 3)",
            shape_str(&a.shape),
        ));
    }
    array_to_cloud(path, "array", &a)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::io::npy::NpyData;

    pub(crate) fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    /// `pickle.dumps(d, protocol=p)` by Python 3.11 + NumPy 2.4 of
    /// d = {ref_points_f: arange(6).reshape(2,3)*0.5, ref_feats_f: [[1,0,0,0],[0,-2,0,0]],
    ///      src_points_f: [[.25,.5,.75]], src_feats_f: [[0,0,3.5,0]]}, all float32.
    const GEO_P2: &str = "80027d710028580c0000007265665f706f696e74735f667101636e756d70792e5f636f72652e6d756c746961727261790a5f7265636f6e7374727563740a7102636e756d70790a6e6461727261790a71034b00857104635f636f646563730a656e636f64650a7105580100000062710658060000006c6174696e31710786710852710987710a52710b284b014b024b0386710c636e756d70790a64747970650a710d58020000006634710e898887710f527110284b0358010000003c71114e4e4e4affffffff4affffffff4b0074711262896805581a000000000000000000003f0000c2803f0000c3803f00000040000020407113680786711452711574711662580b0000007265665f66656174735f667117680268034b00857118680987711952711a284b014b024b0486711b681089680558220000000000c2803f00000000000000000000000000000000000000c3800000000000000000711c680786711d52711e74711f62580c0000007372635f706f696e74735f667120680268034b008571216809877122527123284b014b014b038671246810896805580d0000000000c2803e0000003f0000403f7125680786712652712774712862580b0000007372635f66656174735f667129680268034b0085712a680987712b52712c284b014b014b0486712d6810896805581000000000000000000000000000604000000000712e680786712f52713074713162752e";
    pub(crate) const GEO_P4: &str = "8004957d010000000000007d94288c0c7265665f706f696e74735f66948c166e756d70792e5f636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563749493948c056e756d7079948c076e6461727261799493944b0085944301629487945294284b014b024b03869468058c0564747970659493948c02663494898887945294284b038c013c944e4e4e4affffffff4affffffff4b00749462894318000000000000003f0000803f0000c03f0000004000002040947494628c0b7265665f66656174735f6694680468074b008594680987945294284b014b024b04869468118943200000803f00000000000000000000000000000000000000c00000000000000000947494628c0c7372635f706f696e74735f6694680468074b008594680987945294284b014b014b038694681189430c0000803e0000003f0000403f947494628c0b7372635f66656174735f6694680468074b008594680987945294284b014b014b04869468118943100000000000000000000060400000000094749462752e";
    const GEO_P5: &str = "80059559010000000000007d94288c0c7265665f706f696e74735f66948c136e756d70792e5f636f72652e6e756d65726963948c0b5f66726f6d62756666657294939428961800000000000000000000000000003f0000803f0000c03f0000004000002040948c056e756d7079948c0564747970659493948c02663494898887945294284b038c013c944e4e4e4affffffff4affffffff4b007494624b024b0386948c014394749452948c0b7265665f66656174735f66946804289620000000000000000000803f00000000000000000000000000000000000000c0000000000000000094680b4b024b048694680f749452948c0c7372635f706f696e74735f6694680428960c000000000000000000803e0000003f0000403f94680b4b014b038694680f749452948c0b7372635f66656174735f66946804289610000000000000000000000000000000000060400000000094680b4b014b048694680f74945294752e";
    /// protocol 4 of {big: float64 '>f8' [1.5,-2], n: 7, s: 'text', i: arange(3) int64,
    /// fort: asfortranarray(arange(6, float32).reshape(2,3))}.
    const MIXED_P4: &str = "80049573010000000000007d94288c03626967948c166e756d70792e5f636f72652e6d756c74696172726179948c0c5f7265636f6e7374727563749493948c056e756d7079948c076e6461727261799493944b0085944301629487945294284b014b02859468058c0564747970659493948c02663894898887945294284b038c013e944e4e4e4affffffff4affffffff4b007494628943103ff8000000000000c000000000000000947494628c016e944b078c0173948c0474657874948c016994680468074b008594680987945294284b014b038594680e8c02693894898887945294284b038c013c944e4e4e4affffffff4affffffff4b00749462894318000000000000000001000000000000000200000000000000947494628c04666f727494680468074b008594680987945294284b014b024b038694680e8c02663494898887945294284b0368214e4e4e4affffffff4affffffff4b0074946288431800000000000040400000803f00008040000000400000a04094749462752e";

    fn check_geo(m: &BTreeMap<String, NpyArray>) {
        assert_eq!(m.len(), 4);
        assert_eq!(m["ref_points_f"].shape, vec![2, 3]);
        assert_eq!(
            m["ref_points_f"].data,
            NpyData::F32(vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5])
        );
        assert_eq!(m["ref_feats_f"].shape, vec![2, 4]);
        assert_eq!(m["ref_feats_f"].to_f32()[5], -2.0);
        assert_eq!(m["src_points_f"].to_f32(), vec![0.25, 0.5, 0.75]);
        assert_eq!(m["src_feats_f"].to_f32(), vec![0.0, 0.0, 3.5, 0.0]);
    }

    /// `pickle.dumps(d, protocol=0)` of the same dict (UNICODE opcodes, text ints).
    const GEO_P0: &str = "286470300a567265665f706f696e74735f660a70310a636e756d70792e5f636f72652e6d756c746961727261790a5f7265636f6e7374727563740a70320a28636e756d70790a6e6461727261790a70330a2849300a7470340a635f636f646563730a656e636f64650a70350a2856620a70360a566c6174696e310a70370a7470380a5270390a747031300a527031310a2849310a2849320a49330a747031320a636e756d70790a64747970650a7031330a285666340a7031340a4930300a4930310a747031350a527031360a2849330a563c0a7031370a4e4e4e492d310a492d310a49300a747031380a624930300a67350a28565c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030303f5c75303030305c7530303030803f5c75303030305c7530303030c03f5c75303030305c75303030305c7530303030405c75303030305c753030303020400a7031390a67370a747032300a527032310a747032320a6273567265665f66656174735f660a7032330a67320a2867330a2849300a747032340a67390a747032350a527032360a2849310a2849320a49340a747032370a6731360a4930300a67350a28565c75303030305c7530303030803f5c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c7530303030c05c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030300a7032380a67370a747032390a527033300a747033310a6273567372635f706f696e74735f660a7033320a67320a2867330a2849300a747033330a67390a747033340a527033350a2849310a2849310a49330a747033360a6731360a4930300a67350a28565c75303030305c7530303030803e5c75303030305c75303030305c75303030303f5c75303030305c7530303030403f0a7033370a67370a747033380a527033390a747034300a6273567372635f66656174735f660a7034310a67320a2867330a2849300a747034320a67390a747034330a527034340a2849310a2849310a49340a747034350a6731360a4930300a67350a28565c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c75303030305c753030303060405c75303030305c75303030305c75303030305c75303030300a7034360a67370a747034370a527034380a747034390a62732e";

    #[test]
    fn protocol_0_numpy_pickle() {
        let m = parse_pickle_arrays(Path::new("p0"), &hex(GEO_P0)).unwrap();
        check_geo(&m);
        assert!(matches!(
            raw_unicode_escape(br"a\u00e9\U0001F600\\u"),
            Some(Decoded::Text(t)) if t == "a\u{e9}\u{1F600}\\\\u"
        ));
        assert!(raw_unicode_escape(br"\u12").is_none());
        assert!(raw_unicode_escape(br"\uzzzz").is_none());
    }

    /// A pickle of `levels` nested 1-tuples around an int: `K 0` then `levels` x TUPLE1.
    fn nested_tuples(levels: usize) -> Vec<u8> {
        let mut b = b"\x80\x02K\x00".to_vec();
        b.extend(std::iter::repeat_n(0x85u8, levels));
        b.push(b'.');
        b
    }

    #[test]
    fn deep_nesting_is_a_clear_error_not_a_stack_overflow() {
        // 50,000 levels overflowed the stack when the value was cloned or dropped.
        for bytes in [
            nested_tuples(50_000),
            // Lists through marks: `(` x N then `l` x N.
            {
                let mut b = b"\x80\x02".to_vec();
                b.extend(std::iter::repeat_n(b'(', 50_000));
                b.extend(std::iter::repeat_n(b'l', 50_000));
                b.push(b'.');
                b
            },
            // Empty lists appended into each other: `]` x N then `a` x (N-1).
            {
                let mut b = b"\x80\x02".to_vec();
                b.extend(std::iter::repeat_n(b']', 50_000));
                b.extend(std::iter::repeat_n(b'a', 49_999));
                b.push(b'.');
                b
            },
        ] {
            let e = parse_pickle_arrays(Path::new("deep.pkl"), &bytes)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("deep.pkl") && e.contains("nested at most 1000"),
                "{e}"
            );
            let e = parse_pth_array(Path::new("deep.pth"), &bytes)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("deep.pth") && e.contains("CGENREG_MAX_NESTING"),
                "{e}"
            );
        }
        // Within the limit, nesting is fine (the error is about the shape, not the depth).
        let e = parse_pickle_arrays(Path::new("ok.pkl"), &nested_tuples(900))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a dict of arrays"), "{e}");
        // And through the file readers (the `.pth` cloud path and `--geotransformer-pkl`).
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("deep.pth");
        std::fs::write(&f, nested_tuples(50_000)).unwrap();
        assert!(crate::io::cloud::load_cloud(&f).is_err());
        let f = d.path().join("deep.pkl");
        std::fs::write(&f, nested_tuples(50_000)).unwrap();
        assert!(read_pickle_arrays(&f).is_err());
    }

    #[test]
    fn self_doubling_lists_are_capped() {
        // `]` then (DUP, APPEND) x 60: each step copies the list into itself, 2^60 values.
        let mut b = b"\x80\x02]".to_vec();
        for _ in 0..60 {
            b.extend_from_slice(b"2a");
        }
        b.push(b'.');
        let t = std::time::Instant::now();
        let e = parse_pickle_arrays(Path::new("dbl.pkl"), &b)
            .unwrap_err()
            .to_string();
        assert!(e.contains("values"), "{e}");
        assert!(t.elapsed().as_secs() < 5);
    }

    #[test]
    fn latin1_matches_char_by_char() {
        let s: String = (0u32..256).filter_map(char::from_u32).collect();
        let want: Vec<u8> = s.chars().map(|c| c as u32 as u8).collect();
        assert_eq!(latin1(s.as_bytes()).unwrap(), want);
        assert!(latin1("\u{100}".as_bytes()).is_none());
        assert!(latin1("\u{20ac}".as_bytes()).is_none());
        assert!(latin1(&[0xC3]).is_none());
        assert!(latin1(&[0xC3, 0x41]).is_none());
    }

    #[test]
    fn python_pickles_of_float32_dicts() {
        for (name, h) in [("p2", GEO_P2), ("p4", GEO_P4), ("p5", GEO_P5)] {
            let m = parse_pickle_arrays(Path::new(name), &hex(h)).unwrap();
            check_geo(&m);
        }
        // NumPy 1.x writes `numpy.core.multiarray` (the authors' files): same bytes otherwise.
        let p2 = hex(GEO_P2);
        let from = b"numpy._core.multiarray\n";
        let at = p2.windows(from.len()).position(|w| w == from).unwrap();
        let mut old = p2[..at].to_vec();
        old.extend_from_slice(b"numpy.core.multiarray\n");
        old.extend_from_slice(&p2[at + from.len()..]);
        check_geo(&parse_pickle_arrays(Path::new("old"), &old).unwrap());
    }

    #[test]
    fn big_endian_fortran_and_skipped_values() {
        let m = parse_pickle_arrays(Path::new("mixed"), &hex(MIXED_P4)).unwrap();
        assert_eq!(m.keys().collect::<Vec<_>>(), ["big", "fort"]);
        assert_eq!(m["big"].data, NpyData::F64(vec![1.5, -2.0]));
        assert_eq!(m["fort"].shape, vec![2, 3]);
        assert_eq!(m["fort"].to_f32(), vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn refuses_other_globals_and_bad_input() {
        // pickle.dumps(os.system) style: GLOBAL 'os system'.
        let evil = b"\x80\x02cos\nsystem\nq\x00X\x02\x00\x00\x00lsq\x01\x85q\x02Rq\x03.";
        let e = parse_pickle_arrays(Path::new("evil.pkl"), evil)
            .unwrap_err()
            .to_string();
        assert!(e.contains("evil.pkl") && e.contains("os.system"), "{e}");
        let p4 = hex(GEO_P4);
        let e = parse_pickle_arrays(Path::new("cut.pkl"), &p4[..p4.len() / 2])
            .unwrap_err()
            .to_string();
        assert!(e.contains("cut.pkl") && e.contains("truncated"), "{e}");
        let e = parse_pickle_arrays(Path::new("l.pkl"), b"\x80\x02]q\x00.")
            .unwrap_err()
            .to_string();
        assert!(e.contains("a dict of arrays"), "{e}");
        let e = parse_pth_array(Path::new("z.pth"), b"PK\x03\x04rest")
            .unwrap_err()
            .to_string();
        assert!(e.contains("zip"), "{e}");
    }

    #[test]
    fn staged_pth_files() {
        let Some(root) = crate::testing::test_data_root() else {
            return;
        };
        let m = root.join("3dmatch-redkitchen");
        for (rel, n) in [
            ("regtr/cloud_bin_0.pth", 18_977),
            ("regtr/cloud_bin_5.pth", 19_084),
            ("predator-demo/cloud_bin_21.pth", 25_337),
            ("predator-demo/cloud_bin_34.pth", 14_602),
        ] {
            let a = read_pth_array(&m.join(rel)).unwrap();
            assert_eq!(a.shape, vec![n, 3], "{rel}");
            assert!(matches!(a.data, NpyData::F64(_)));
            assert_eq!(read_pth_points(&m.join(rel)).unwrap().len(), n);
        }
        // RegTR's cloud_bin_0 and GeoTransformer's ref.npy are the same downsampled cloud.
        let a = read_pth_array(&m.join("regtr/cloud_bin_0.pth")).unwrap();
        let b = crate::io::npy::read_npy(&m.join("geotransformer-demo/ref.npy")).unwrap();
        assert_eq!(a.shape, b.shape);
        let (mut sa, mut sb) = (a.to_f64(), b.to_f64());
        let key = |v: &mut Vec<f64>| {
            let mut rows: Vec<[f64; 3]> = v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            rows.sort_by(|x, y| x.partial_cmp(y).unwrap());
            *v = rows.concat();
        };
        key(&mut sa);
        key(&mut sb);
        let max = sa
            .iter()
            .zip(&sb)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(max < 1e-6, "max diff {max}");
    }
}
