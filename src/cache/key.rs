//! Cache keys: blake3 of the canonical JSON of (stage, version, inputs, parameters), and the
//! content hashes of raw inputs.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

/// Identifies one stage output: the stage, its version, the keys of its inputs and its
/// parameters. `hash` is derived from all of them.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CacheKey {
    pub stage: String,
    pub version: u32,
    /// Hashes of the inputs (other entries' keys, or content hashes of input files).
    pub inputs: Vec<String>,
    pub params: Value,
    /// 64 hex digits.
    pub hash: String,
}

impl CacheKey {
    pub fn new(stage: &str, version: u32, inputs: &[&str], params: &Value) -> Result<CacheKey> {
        if stage.is_empty()
            || !stage
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err(Error::Param(format!(
                "cache stage name {stage:?}: use letters, digits, '_' and '-'"
            )));
        }
        let params = canonical(params);
        let doc = serde_json::json!({
            "stage": stage, "version": version, "inputs": inputs, "params": params,
        });
        let hash = blake3::hash(canonical_string(&doc).as_bytes())
            .to_hex()
            .to_string();
        Ok(CacheKey {
            stage: stage.to_string(),
            version,
            inputs: inputs.iter().map(|s| s.to_string()).collect(),
            params,
            hash,
        })
    }

    /// Short form for display: `stage/0123456789ab`.
    pub fn short(&self) -> String {
        format!("{}/{}", self.stage, &self.hash[..12.min(self.hash.len())])
    }
}

/// blake3 of bytes, hex (for content-hashing raw inputs such as a depth video).
pub fn hash_bytes(bytes: &[u8]) -> String {
    blake3::hash(bytes).to_hex().to_string()
}

/// blake3 of a file's content, hex.
pub fn hash_file(path: &Path) -> Result<String> {
    let mut h = blake3::Hasher::new();
    // an input: regular files only (a FIFO would block the hash forever), bounded
    let (f, len) = crate::io::limits::open_input(path)?;
    std::io::copy(&mut std::io::Read::take(f, len), &mut h).map_err(|e| Error::io(path, e))?;
    Ok(h.finalize().to_hex().to_string())
}

/// JSON with object keys sorted at every level (independent of serde_json's map order).
pub fn canonical(v: &Value) -> Value {
    match v {
        Value::Object(m) => {
            let mut keys: Vec<&String> = m.keys().collect();
            keys.sort();
            let mut out = serde_json::Map::new();
            for k in keys {
                out.insert(k.clone(), canonical(&m[k]));
            }
            Value::Object(out)
        }
        Value::Array(a) => Value::Array(a.iter().map(canonical).collect()),
        other => other.clone(),
    }
}

/// Compact serialisation with sorted keys, written by hand so the map type cannot reorder it.
fn canonical_string(v: &Value) -> String {
    let mut s = String::new();
    write_canonical(v, &mut s);
    s
}

fn write_canonical(v: &Value, s: &mut String) {
    match v {
        Value::Object(m) => {
            let mut keys: Vec<&String> = m.keys().collect();
            keys.sort();
            s.push('{');
            for (i, k) in keys.into_iter().enumerate() {
                if i > 0 {
                    s.push(',');
                }
                s.push_str(&Value::String(k.clone()).to_string());
                s.push(':');
                write_canonical(&m[k], s);
            }
            s.push('}');
        }
        Value::Array(a) => {
            s.push('[');
            for (i, x) in a.iter().enumerate() {
                if i > 0 {
                    s.push(',');
                }
                write_canonical(x, s);
            }
            s.push(']');
        }
        other => s.push_str(&other.to_string()),
    }
}
