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
            return Err(Error::Invalid(format!(
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
    let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    h.update_reader(f).map_err(|e| Error::io(path, e))?;
    Ok(h.finalize().to_hex().to_string())
}

/// [`hash_file`] memoised by (path, length, modification time): the stage keys hash the same
/// input files (depth frames, colour frames, model files) on every key computation, and the
/// inspector computes every stage's key on each settings change. A file rewritten in place
/// changes its modification time (or length), so its content is hashed again. At most
/// [`FILE_HASH_MEMO`] files are remembered (the oldest is dropped first).
pub fn hash_file_memo(path: &Path) -> Result<String> {
    use std::collections::HashMap;
    use std::sync::{Mutex, OnceLock};
    type Stamp = (u64, Option<std::time::SystemTime>);
    type Memo = (HashMap<std::path::PathBuf, (Stamp, String, u64)>, u64);
    static MEMO: OnceLock<Mutex<Memo>> = OnceLock::new();
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let stamp: Stamp = (meta.len(), meta.modified().ok());
    // without a modification time the file cannot be told apart from a rewrite: hash it
    if stamp.1.is_none() {
        return hash_file(path);
    }
    let memo = MEMO.get_or_init(Default::default);
    if let Ok(m) = memo.lock() {
        if let Some((s, h, _)) = m.0.get(path) {
            if *s == stamp {
                return Ok(h.clone());
            }
        }
    }
    let h = hash_file(path)?;
    if let Ok(mut m) = memo.lock() {
        let (map, clock) = &mut *m;
        *clock += 1;
        if map.len() >= FILE_HASH_MEMO && !map.contains_key(path) {
            if let Some(oldest) = map
                .iter()
                .min_by_key(|(_, (_, _, t))| *t)
                .map(|(p, _)| p.clone())
            {
                map.remove(&oldest);
            }
        }
        map.insert(path.to_path_buf(), (stamp, h.clone(), *clock));
    }
    Ok(h)
}

/// Files [`hash_file_memo`] remembers (a pair's 2L depth frames, 2L colour frames and the
/// model file, for several pairs).
pub const FILE_HASH_MEMO: usize = 4096;

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memoised_file_hash_follows_rewrites() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.bin");
        std::fs::write(&p, b"first").unwrap();
        let a = hash_file_memo(&p).unwrap();
        assert_eq!(a, hash_file(&p).unwrap());
        assert_eq!(hash_file_memo(&p).unwrap(), a);
        // a rewrite with other content (same length, later time) is hashed again
        let f = std::fs::File::options().write(true).open(&p).unwrap();
        std::io::Write::write_all(&mut &f, b"other").unwrap();
        let later = std::time::SystemTime::now() + std::time::Duration::from_secs(5);
        f.set_modified(later).unwrap();
        drop(f);
        let b = hash_file_memo(&p).unwrap();
        assert_eq!(b, hash_file(&p).unwrap());
        assert_ne!(a, b);
        // a longer file, too
        std::fs::write(&p, b"a longer content").unwrap();
        assert_eq!(hash_file_memo(&p).unwrap(), hash_file(&p).unwrap());
        assert!(hash_file_memo(&dir.path().join("missing")).is_err());
    }
}
