//! The pickle machine: the values plain data and NumPy arrays pickle to, and the opcodes of
//! protocols 0-5 that build them (see the module above for what is accepted and refused).

use crate::error::{Error, Result};
use crate::io::npy::parse_descr;
use std::collections::HashMap;
use std::path::Path;
use std::rc::Rc;

/// `torch.save`'s legacy magic number, the first pickle of a `.pth` file.
pub(super) const TORCH_MAGIC: i128 = 0x1950a86a20f9469cfc6c;

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Global {
    Reconstruct,
    NdArray,
    Dtype,
    CodecsEncode,
    FromBuffer,
    OrderedDict,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Dtype {
    pub(super) kind: char,
    pub(super) size: usize,
    pub(super) big: bool,
}

#[derive(Clone, Debug)]
pub(super) struct PyArray {
    pub(super) dtype: Option<Dtype>,
    pub(super) shape: Vec<usize>,
    pub(super) fortran: bool,
    pub(super) data: Option<Rc<Vec<u8>>>,
}

#[derive(Clone, Debug)]
pub(super) enum Value {
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
    pub(super) fn id(&self) -> Option<u64> {
        match self {
            Value::List(id, _) | Value::Dict(id, _) | Value::Array(id, _) | Value::Dtype(id, _) => {
                Some(*id)
            }
            // Tuples are immutable: no memo refresh needed.
            Value::Tuple(..) => None,
            _ => None,
        }
    }
    pub(super) fn type_name(&self) -> &'static str {
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
    pub(super) fn as_shape(&self) -> Option<Vec<usize>> {
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
    pub(super) fn as_raw_bytes(&self) -> Option<Rc<Vec<u8>>> {
        match self {
            Value::Bytes(b) | Value::Latin1(b) => Some(b.clone()),
            Value::Str(s) => latin1(s.as_bytes()).map(Rc::new),
            _ => None,
        }
    }
}

/// Encode UTF-8 text as latin-1, or None if it is not valid UTF-8 made only of chars
/// <= U+00FF (1 byte, or 0xC2/0xC3 followed by a continuation byte).
pub(super) fn latin1(b: &[u8]) -> Option<Vec<u8>> {
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

pub(super) enum Decoded {
    /// Every char is <= U+00FF: kept as latin-1 bytes.
    Latin1(Vec<u8>),
    Text(String),
}

/// Decode Python's `raw-unicode-escape`: each byte is the char of that code, except
/// `\uXXXX` and `\UXXXXXXXX` (an odd run of backslashes before `u`/`U` starts an escape).
pub(super) fn raw_unicode_escape(b: &[u8]) -> Option<Decoded> {
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

pub(super) struct Vm<'a> {
    pub(super) path: &'a Path,
    pub(super) data: &'a [u8],
    pub(super) pos: usize,
    /// Which pickle of the file (0-based), for error messages.
    pub(super) index: usize,
    pub(super) stack: Vec<Value>,
    pub(super) marks: Vec<usize>,
    pub(super) memo: HashMap<u32, Value>,
    pub(super) memo_of: HashMap<u64, Vec<u32>>,
    pub(super) next_id: u64,
    /// Nesting depth of every container built so far (by identity), and the limit: deep
    /// nesting would overflow the stack when the values are cloned, printed or dropped.
    /// Also their size in values: memo gets and DUP copy values (Python shares them), so a
    /// list appended to itself would double each time without a cap.
    pub(super) depth: HashMap<u64, (usize, u64)>,
    pub(super) max_depth: usize,
    pub(super) max_values: u64,
    /// Values copied so far by memo gets and DUP, capped by `max_values` too.
    pub(super) copied: u64,
}

impl<'a> Vm<'a> {
    pub(super) fn new(path: &'a Path, data: &'a [u8]) -> Self {
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

    pub(super) fn err(&self, expected: impl Into<String>, found: impl Into<String>) -> Error {
        Error::format(
            self.path,
            format!("pickle {} at byte {}", self.index, self.pos),
            expected,
            found,
        )
    }

    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8]> {
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
    pub(super) fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    pub(super) fn u16(&mut self) -> Result<u16> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    pub(super) fn u32(&mut self) -> Result<u32> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    pub(super) fn u64(&mut self) -> Result<usize> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        usize::try_from(u64::from_le_bytes(a)).map_err(|_| self.err("a sane length", "too large"))
    }
    pub(super) fn line(&mut self) -> Result<&'a str> {
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
    pub(super) fn weight(&self, v: &Value) -> (usize, u64) {
        match v {
            Value::Tuple(id, _) | Value::List(id, _) | Value::Dict(id, _) => {
                self.depth.get(id).copied().unwrap_or((1, 1))
            }
            _ => (0, 1),
        }
    }
    /// A new container holding `items`: its identity, after checking the nesting limit.
    pub(super) fn container(&mut self, items: &[Value]) -> Result<u64> {
        let refs: Vec<&Value> = items.iter().collect();
        self.container_of(&refs)
    }
    pub(super) fn container_of(&mut self, items: &[&Value]) -> Result<u64> {
        let id = self.new_id();
        self.depth.insert(id, (1, 1));
        self.grow_of(id, items)?;
        Ok(id)
    }
    /// Container `id` receives `items`: raise its depth, failing past the limit.
    pub(super) fn grow(&mut self, id: u64, items: &[Value]) -> Result<()> {
        let refs: Vec<&Value> = items.iter().collect();
        self.grow_of(id, &refs)
    }
    pub(super) fn grow_of(&mut self, id: u64, items: &[&Value]) -> Result<()> {
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
    pub(super) fn count_copy(&mut self, v: &Value) -> Result<()> {
        self.copied = self.copied.saturating_add(self.weight(v).1);
        if self.copied > self.max_values {
            return Err(self.err(
                format!("at most {} values copied by memo gets", self.max_values),
                format!("{} values", self.copied),
            ));
        }
        Ok(())
    }
    pub(super) fn new_id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id
    }
    pub(super) fn pop(&mut self) -> Result<Value> {
        if self.marks.last() == Some(&self.stack.len()) {
            return Err(self.err("a value on the stack", "a mark"));
        }
        self.stack
            .pop()
            .ok_or_else(|| self.err("a value on the stack", "an empty stack"))
    }
    pub(super) fn pop_mark(&mut self) -> Result<Vec<Value>> {
        let m = self
            .marks
            .pop()
            .ok_or_else(|| self.err("a mark on the stack", "none"))?;
        Ok(self.stack.split_off(m))
    }
    pub(super) fn top(&mut self) -> Result<&mut Value> {
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
    pub(super) fn put(&mut self, key: u32) -> Result<()> {
        let v = self.top()?.clone();
        if let Some(id) = v.id() {
            self.memo_of.entry(id).or_default().push(key);
        }
        self.memo.insert(key, v);
        Ok(())
    }
    pub(super) fn get(&mut self, key: u32) -> Result<()> {
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
    pub(super) fn sync_top(&mut self) -> Result<()> {
        let top = self.top()?.clone();
        if let Some(keys) = top.id().and_then(|id| self.memo_of.get(&id)) {
            for k in keys {
                self.memo.insert(*k, top.clone());
            }
        }
        Ok(())
    }
    pub(super) fn int(&self, v: &[u8]) -> Result<Value> {
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
    pub(super) fn str(&self, b: &[u8]) -> Result<Value> {
        std::str::from_utf8(b)
            .map(|s| Value::Str(Rc::from(s)))
            .map_err(|_| self.err("UTF-8 text", "invalid UTF-8"))
    }

    pub(super) fn global(&self, module: &str, name: &str) -> Result<Global> {
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

    pub(super) fn call(&mut self, f: Value, args: Value) -> Result<Value> {
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

    pub(super) fn build(&mut self, state: Value) -> Result<()> {
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
    pub(super) fn run(&mut self) -> Result<Value> {
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
