//! Content-addressed stage cache with provenance.
//!
//! Layout: `<root>/<stage>/<hash>/` holds the payload files and `manifest.json`. The hash is the
//! blake3 of the canonical JSON of (stage, stage version, input keys, parameters), so a change
//! to any input or parameter gives a new entry and re-runs exactly the stages that depend on it.
//!
//! `manifest.json` (format 1): `{format, stage, version, key, inputs, params, provenance,
//! created_unix, files: [{name, size, blake3}]}`. `provenance` is free JSON (backend, model,
//! command, prompt, seed, ...).
//!
//! Writes are atomic, also for several processes on several hosts sharing the cache over NFS,
//! with no reliance on `flock`: an entry is built in a private folder
//! `<root>/<stage>/.tmp-<hash>-<host>-<pid>-<n>-<ns>` (a name no other writer uses), its files
//! and the folder are synced, then it is renamed to `<root>/<stage>/<hash>` in the same
//! directory, so readers see either nothing or a complete entry. When another writer placed the
//! same key first, the rename fails and its verified entry is used (same key, same inputs: as
//! good as ours). Removal renames the entry to a `.trash-...` name in the same directory first.
//! Names starting with `.` are never entries. [`Cache::get`] re-hashes every file against the
//! manifest; a corrupt or partial entry is an error, never returned as data. Payload helpers:
//! f32 matrices and [`Features`] as `.npy` (little-endian f32, C order, 2-D), images as PNG,
//! JSON as pretty-printed UTF-8.

use crate::error::{Error, Result};
use crate::features::Features;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::{Path, PathBuf};

pub const MANIFEST: &str = "manifest.json";
/// The file that marks a directory as a cgenreg cache: commands that delete refuse a
/// directory without it.
pub const MARKER: &str = "cgenreg-cache.json";
const FORMAT: u32 = 1;

/// The default cache directory: `$CGENREG_CACHE`, else `~/.cache/cgenreg`.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("CGENREG_CACHE").filter(|d| !d.is_empty()) {
        return PathBuf::from(d);
    }
    match std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        Some(h) => PathBuf::from(h).join(".cache").join("cgenreg"),
        None => PathBuf::from(".cgenreg-cache"),
    }
}

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

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileRecord {
    pub name: String,
    pub size: u64,
    pub blake3: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: u32,
    pub stage: String,
    pub version: u32,
    pub key: String,
    pub inputs: Vec<String>,
    pub params: Value,
    pub provenance: Value,
    pub created_unix: u64,
    pub files: Vec<FileRecord>,
}

/// A verified entry.
#[derive(Clone, Debug)]
pub struct Entry {
    pub dir: PathBuf,
    pub manifest: Manifest,
}

/// What `list` knows without re-hashing payloads.
#[derive(Clone, Debug)]
pub struct EntrySummary {
    pub stage: String,
    pub hash: String,
    pub dir: PathBuf,
    /// None when the manifest could not be read (partial or foreign entry); see `problem`.
    pub manifest: Option<Manifest>,
    pub total_bytes: u64,
    pub problem: Option<String>,
}

#[derive(Clone, Debug)]
pub struct VerifyReport {
    pub stage: String,
    pub hash: String,
    pub dir: PathBuf,
    /// Ok, or what is wrong with the entry.
    pub result: std::result::Result<(), String>,
}

#[derive(Clone, Debug)]
pub struct Cache {
    root: PathBuf,
}

fn check_name(name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name != MANIFEST
        && !name.starts_with('/')
        && name
            .split('/')
            .all(|c| !c.is_empty() && c != "." && c != ".." && !c.contains('\\'));
    if ok {
        Ok(())
    } else {
        Err(Error::Invalid(format!(
            "cache file name {name:?}: must be a relative path without '..' and not {MANIFEST}"
        )))
    }
}

/// Whether `name` is an entry folder's name: the 64 lowercase hex digits of a key hash.
fn is_entry_name(name: &str) -> bool {
    name.len() == 64
        && name
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Whether `name` can be a stage folder's name (as [`CacheKey::new`] allows).
fn is_stage_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// The marker file's content.
#[derive(Serialize, Deserialize)]
struct Marker {
    tool: String,
    format: u32,
    created_unix: u64,
}

impl Cache {
    /// Open (creating if needed) a cache rooted at `dir`. A new or empty directory gets the
    /// marker file [`MARKER`]; an existing one without it is read and written as before, but
    /// the cache commands that delete refuse it until `cgenreg cache init` marks it.
    pub fn open(dir: impl Into<PathBuf>) -> Result<Cache> {
        let root = dir.into();
        std::fs::create_dir_all(&root).map_err(|e| Error::io(&root, e))?;
        let c = Cache { root };
        let empty = std::fs::read_dir(&c.root)
            .map_err(|e| Error::io(&c.root, e))?
            .next()
            .is_none();
        if empty {
            c.init()?;
        }
        Ok(c)
    }

    /// A cache at `dir` as it is: nothing is created (the cache commands use this; a missing
    /// directory lists as empty).
    pub fn at(dir: impl Into<PathBuf>) -> Cache {
        Cache { root: dir.into() }
    }

    /// Whether the directory carries the marker of a cgenreg cache.
    pub fn is_marked(&self) -> bool {
        self.root.join(MARKER).is_file()
    }

    /// Mark the directory as a cgenreg cache (created when missing); false when it was
    /// marked already.
    pub fn init(&self) -> Result<bool> {
        if self.is_marked() {
            return Ok(false);
        }
        std::fs::create_dir_all(&self.root).map_err(|e| Error::io(&self.root, e))?;
        let m = Marker {
            tool: "cgenreg".into(),
            format: FORMAT,
            created_unix: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs())
                .unwrap_or(0),
        };
        let b = serde_json::to_vec_pretty(&m)
            .map_err(|e| Error::Invalid(format!("serialising the cache marker: {e}")))?;
        crate::error::write_atomic(&self.root.join(MARKER), &b)?;
        Ok(true)
    }

    /// [`Error::NotACache`] unless the directory carries the marker: checked before a
    /// command deletes anything.
    fn require_marker(&self) -> Result<()> {
        if self.is_marked() {
            Ok(())
        } else {
            Err(Error::NotACache {
                dir: self.root.clone(),
                marker: MARKER.into(),
            })
        }
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    fn entry_dir(&self, stage: &str, hash: &str) -> PathBuf {
        self.root.join(stage).join(hash)
    }

    /// The verified entry for `key`, None when absent, an error when present but corrupt or
    /// partial (the entry is left in place for inspection; `remove` clears it).
    pub fn get(&self, key: &CacheKey) -> Result<Option<Entry>> {
        let dir = self.entry_dir(&key.stage, &key.hash);
        if !dir.exists() {
            return Ok(None);
        }
        let manifest = verify_dir(&dir).map_err(Error::Cache)?;
        if manifest.key != key.hash || manifest.stage != key.stage {
            return Err(Error::Cache(format!(
                "{}: manifest is for {}/{}, expected {}",
                dir.display(),
                manifest.stage,
                manifest.key,
                key.short()
            )));
        }
        Ok(Some(Entry { dir, manifest }))
    }

    /// Start a new entry for `key`; nothing is visible until [`NewEntry::commit`].
    pub fn put(&self, key: &CacheKey, provenance: Value) -> Result<NewEntry> {
        let stage_dir = self.root.join(&key.stage);
        std::fs::create_dir_all(&stage_dir).map_err(|e| Error::io(&stage_dir, e))?;
        let tmp = stage_dir.join(format!(
            ".tmp-{}-{}",
            &key.hash[..16],
            crate::error::unique_suffix()
        ));
        // create_dir, not create_dir_all: a folder that exists belongs to another writer.
        std::fs::create_dir(&tmp).map_err(|e| Error::io(&tmp, e))?;
        Ok(NewEntry {
            cache: self.clone(),
            key: key.clone(),
            provenance,
            tmp,
            files: Vec::new(),
            committed: false,
        })
    }

    /// Every entry directory with its manifest (payloads not re-hashed; see `verify_all`).
    pub fn list(&self) -> Result<Vec<EntrySummary>> {
        let mut out = Vec::new();
        for (stage, hash, dir) in self.entry_dirs()? {
            let mp = dir.join(MANIFEST);
            let (manifest, problem) = match std::fs::read(&mp) {
                Err(e) => (None, Some(format!("partial entry: {MANIFEST}: {e}"))),
                Ok(b) => match serde_json::from_slice::<Manifest>(&b) {
                    Ok(m) => (Some(m), None),
                    Err(e) => (None, Some(format!("{MANIFEST} unreadable: {e}"))),
                },
            };
            let total_bytes = manifest
                .as_ref()
                .map(|m| m.files.iter().map(|f| f.size).sum())
                .unwrap_or(0);
            out.push(EntrySummary {
                stage,
                hash,
                dir,
                manifest,
                total_bytes,
                problem,
            });
        }
        Ok(out)
    }

    /// Re-hash every entry.
    pub fn verify_all(&self) -> Result<Vec<VerifyReport>> {
        use rayon::prelude::*;
        let dirs = self.entry_dirs()?;
        Ok(dirs
            .into_par_iter()
            .map(|(stage, hash, dir)| {
                let result = verify_dir(&dir).and_then(|m| {
                    if m.key == hash && m.stage == stage {
                        Ok(())
                    } else {
                        Err(format!("manifest names {}/{}", m.stage, m.key))
                    }
                });
                VerifyReport {
                    stage,
                    hash,
                    dir,
                    result,
                }
            })
            .collect())
    }

    /// Remove the entry of `key` (a no-op when absent): the pipeline's own removal of a
    /// corrupt entry, at the exact path its key names. Returns whether something was removed.
    pub fn remove(&self, key: &CacheKey) -> Result<bool> {
        let dir = self.entry_dir(&key.stage, &key.hash);
        if !is_stage_name(&key.stage) || !is_entry_name(&key.hash) || !dir.is_dir() {
            return Ok(false);
        }
        self.discard(&dir)?;
        Ok(true)
    }

    /// Remove the entry `<stage>/<hash>`; `hash` may be a unique prefix (as `list` prints it).
    /// Only in a marked cache ([`Error::NotACache`] otherwise), and only entry folders.
    pub fn remove_entry(&self, stage: &str, hash: &str) -> Result<bool> {
        self.require_marker()?;
        let stage_dir = self.root.join(stage);
        if !is_stage_name(stage) || !stage_dir.is_dir() {
            return Ok(false);
        }
        let matches: Vec<PathBuf> = std::fs::read_dir(&stage_dir)
            .map_err(|e| Error::io(&stage_dir, e))?
            .flatten()
            .filter(|e| {
                let n = e.file_name().to_string_lossy().into_owned();
                !hash.is_empty() && is_entry_name(&n) && n.starts_with(hash) && e.path().is_dir()
            })
            .map(|e| e.path())
            .collect();
        match matches.len() {
            0 => Ok(false),
            1 => {
                owned_entry(&matches[0]).map_err(Error::Cache)?;
                self.discard(&matches[0])?;
                Ok(true)
            }
            n => Err(Error::Invalid(format!(
                "{n} entries of stage {stage} start with {hash}; give more digits"
            ))),
        }
    }

    /// Remove every entry of every stage (only in a marked cache; only entry folders: any
    /// other file or folder stays). Returns how many were removed.
    pub fn remove_all(&self) -> Result<usize> {
        self.require_marker()?;
        let stages: std::collections::BTreeSet<String> =
            self.entry_dirs()?.into_iter().map(|(s, _, _)| s).collect();
        let mut n = 0;
        for s in stages {
            n += self.remove_stage(&s)?;
        }
        Ok(n)
    }

    /// Remove every entry of a stage (only in a marked cache; only entry folders). Returns
    /// how many were removed.
    pub fn remove_stage(&self, stage: &str) -> Result<usize> {
        self.require_marker()?;
        let mut n = 0;
        for (s, _, dir) in self.entry_dirs()? {
            if s == stage && owned_entry(&dir).is_ok() {
                self.discard(&dir)?;
                n += 1;
            }
        }
        // The stage folder goes when it held entries and nothing else is left in it.
        let d = self.root.join(stage);
        if n > 0 && d.is_dir() {
            let _ = std::fs::remove_dir(&d);
        }
        Ok(n)
    }

    /// Move aside atomically (a `.trash-...` name in the same directory), then delete:
    /// readers never see a half-deleted entry. Once renamed the entry is gone; a delete that
    /// fails (e.g. NFS keeps a file another host still has open) leaves only a dot-folder.
    fn discard(&self, dir: &Path) -> Result<()> {
        let parent = dir.parent().unwrap_or(&self.root);
        let trash = parent.join(format!(".trash-{}", crate::error::unique_suffix()));
        std::fs::rename(dir, &trash).map_err(|e| Error::io(dir, e))?;
        let _ = std::fs::remove_dir_all(&trash);
        Ok(())
    }

    /// Every entry folder: `<stage>/<64 hex digits>`. Anything else (writers' private
    /// dot-folders and trash, files, folders with other names) is never an entry.
    fn entry_dirs(&self) -> Result<Vec<(String, String, PathBuf)>> {
        let mut out = Vec::new();
        if !self.root.exists() {
            return Ok(out);
        }
        let rd = std::fs::read_dir(&self.root).map_err(|e| Error::io(&self.root, e))?;
        for s in rd.flatten() {
            let stage = s.file_name().to_string_lossy().into_owned();
            if !is_stage_name(&stage) || !s.path().is_dir() {
                continue;
            }
            let sd = s.path();
            let rd2 = std::fs::read_dir(&sd).map_err(|e| Error::io(&sd, e))?;
            for h in rd2.flatten() {
                if h.path().is_dir() && is_entry_name(&h.file_name().to_string_lossy()) {
                    out.push((
                        stage.clone(),
                        h.file_name().to_string_lossy().into_owned(),
                        h.path(),
                    ));
                }
            }
        }
        out.sort();
        Ok(out)
    }
}

/// Ok when `dir` is an entry this cache wrote: its `manifest.json` parses (as far as the
/// stage and key) and names the folder it is in. The commands delete nothing else, so a
/// user's folder that happens to have an entry's name survives; an entry whose manifest is
/// gone or unreadable is reported and left for the user (or replaced by the pipeline when it
/// writes that key again).
pub fn owned_entry(dir: &Path) -> std::result::Result<(), String> {
    #[derive(Deserialize)]
    struct Names {
        stage: String,
        key: String,
    }
    let mp = dir.join(MANIFEST);
    let n: Names = std::fs::read(&mp)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .ok_or_else(|| {
            format!(
                "{}: no readable {MANIFEST}, so not removed (delete it by hand if it is a \
                 broken entry)",
                dir.display()
            )
        })?;
    let hash = dir.file_name().map(|h| h.to_string_lossy().into_owned());
    let stage = dir
        .parent()
        .and_then(|p| p.file_name())
        .map(|s| s.to_string_lossy().into_owned());
    if hash.as_deref() == Some(n.key.as_str()) && stage.as_deref() == Some(n.stage.as_str()) {
        Ok(())
    } else {
        Err(format!(
            "{}: its {MANIFEST} names {}/{}, so not removed",
            dir.display(),
            n.stage,
            n.key
        ))
    }
}

/// Read the manifest and re-hash every listed file.
fn verify_dir(dir: &Path) -> std::result::Result<Manifest, String> {
    let mp = dir.join(MANIFEST);
    let bytes = std::fs::read(&mp)
        .map_err(|e| format!("partial entry {}: {MANIFEST}: {e}", dir.display()))?;
    let m: Manifest = serde_json::from_slice(&bytes)
        .map_err(|e| format!("corrupt entry {}: {MANIFEST}: {e}", dir.display()))?;
    if m.format != FORMAT {
        return Err(format!(
            "{}: manifest format {}, this build reads {FORMAT}",
            dir.display(),
            m.format
        ));
    }
    for f in &m.files {
        check_name(&f.name).map_err(|e| format!("{}: {e}", dir.display()))?;
        let p = dir.join(&f.name);
        let meta = std::fs::metadata(&p)
            .map_err(|e| format!("partial entry {}: {}: {e}", dir.display(), f.name))?;
        if meta.len() != f.size {
            return Err(format!(
                "corrupt entry {}: {}: {} bytes, manifest says {}",
                dir.display(),
                f.name,
                meta.len(),
                f.size
            ));
        }
        let h = hash_file(&p).map_err(|e| e.to_string())?;
        if h != f.blake3 {
            return Err(format!(
                "corrupt entry {}: {}: content hash differs from the manifest",
                dir.display(),
                f.name
            ));
        }
    }
    Ok(m)
}

/// An entry being written (in a private temporary directory).
pub struct NewEntry {
    cache: Cache,
    key: CacheKey,
    provenance: Value,
    tmp: PathBuf,
    files: Vec<FileRecord>,
    committed: bool,
}

impl NewEntry {
    /// Add a payload file (name may contain '/' for sub-folders).
    pub fn add_bytes(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        check_name(name)?;
        if self.files.iter().any(|f| f.name == name) {
            return Err(Error::Invalid(format!("cache file {name} added twice")));
        }
        let p = self.tmp.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        }
        write_synced(&p, bytes)?;
        self.files.push(FileRecord {
            name: name.to_string(),
            size: bytes.len() as u64,
            blake3: hash_bytes(bytes),
        });
        Ok(())
    }

    pub fn add_json<T: Serialize + ?Sized>(&mut self, name: &str, value: &T) -> Result<()> {
        let b = serde_json::to_vec_pretty(value)
            .map_err(|e| Error::Invalid(format!("serialising {name}: {e}")))?;
        self.add_bytes(name, &b)
    }

    pub fn add_f32_matrix(
        &mut self,
        name: &str,
        rows: usize,
        cols: usize,
        data: &[f32],
    ) -> Result<()> {
        self.add_bytes(name, &encode_npy_f32(rows, cols, data)?)
    }

    pub fn add_features(&mut self, name: &str, f: &Features) -> Result<()> {
        self.add_f32_matrix(name, f.len(), f.dim, &f.data)
    }

    pub fn add_png(&mut self, name: &str, img: &image::RgbImage) -> Result<()> {
        let mut buf = std::io::Cursor::new(Vec::new());
        img.write_to(&mut buf, image::ImageFormat::Png)
            .map_err(|e| Error::Invalid(format!("encoding {name} as PNG: {e}")))?;
        self.add_bytes(name, buf.get_ref())
    }

    /// Write the manifest and move the entry into place. When another writer committed the
    /// same key first, its (verified) entry is kept and returned; a corrupt one is replaced.
    pub fn commit(mut self) -> Result<Entry> {
        let manifest = Manifest {
            format: FORMAT,
            stage: self.key.stage.clone(),
            version: self.key.version,
            key: self.key.hash.clone(),
            inputs: self.key.inputs.clone(),
            params: self.key.params.clone(),
            provenance: self.provenance.clone(),
            created_unix: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs())
                .unwrap_or(0),
            files: self.files.clone(),
        };
        let mp = self.tmp.join(MANIFEST);
        let b = serde_json::to_vec_pretty(&manifest)
            .map_err(|e| Error::Invalid(format!("serialising the manifest: {e}")))?;
        write_synced(&mp, &b)?;
        sync_dir(&self.tmp);
        let dest = self.cache.entry_dir(&self.key.stage, &self.key.hash);
        let stage_dir = self.cache.root.join(&self.key.stage);
        for attempt in 0..2 {
            match std::fs::rename(&self.tmp, &dest) {
                Ok(()) => {
                    sync_dir(&stage_dir);
                    self.committed = true;
                    return Ok(Entry {
                        dir: dest,
                        manifest,
                    });
                }
                Err(e) if dest.exists() => match self.cache.get(&self.key) {
                    Ok(Some(existing)) => {
                        // Same key, same inputs: the other writer's result is as good as ours.
                        let _ = std::fs::remove_dir_all(&self.tmp);
                        self.committed = true;
                        return Ok(existing);
                    }
                    _ if attempt == 0 => {
                        let _ = self.cache.discard(&dest);
                    }
                    _ => return Err(Error::io(&dest, e)),
                },
                Err(e) => return Err(Error::io(&dest, e)),
            }
        }
        Err(Error::Cache(format!("could not place {}", dest.display())))
    }
}

/// Write and sync a file (an entry's files reach the disk, or the server, before its rename).
fn write_synced(p: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let mut f = std::fs::File::create(p).map_err(|e| Error::io(p, e))?;
    f.write_all(bytes).map_err(|e| Error::io(p, e))?;
    f.sync_all().map_err(|e| Error::io(p, e))
}

/// Best-effort sync of a directory's entries (not supported everywhere; never an error).
fn sync_dir(d: &Path) {
    if let Ok(f) = std::fs::File::open(d) {
        let _ = f.sync_all();
    }
}

impl Drop for NewEntry {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.tmp);
        }
    }
}

impl Entry {
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    pub fn provenance(&self) -> &Value {
        &self.manifest.provenance
    }

    pub fn read_bytes(&self, name: &str) -> Result<Vec<u8>> {
        check_name(name)?;
        if !self.manifest.files.iter().any(|f| f.name == name) {
            return Err(Error::Cache(format!(
                "{}: no file {name} in this entry",
                self.dir.display()
            )));
        }
        let p = self.path(name);
        std::fs::read(&p).map_err(|e| Error::io(&p, e))
    }

    pub fn read_json<T: serde::de::DeserializeOwned>(&self, name: &str) -> Result<T> {
        let b = self.read_bytes(name)?;
        serde_json::from_slice(&b)
            .map_err(|e| Error::format(self.path(name), "json", "the stage's JSON", e.to_string()))
    }

    /// (rows, cols, data).
    pub fn read_f32_matrix(&self, name: &str) -> Result<(usize, usize, Vec<f32>)> {
        decode_npy_f32(&self.read_bytes(name)?, &self.path(name))
    }

    pub fn read_features(&self, name: &str) -> Result<Features> {
        let (_, cols, data) = self.read_f32_matrix(name)?;
        Ok(Features::new(cols, data))
    }

    pub fn read_png(&self, name: &str) -> Result<image::RgbImage> {
        let b = self.read_bytes(name)?;
        image::load_from_memory_with_format(&b, image::ImageFormat::Png)
            .map(|i| i.to_rgb8())
            .map_err(|e| Error::format(self.path(name), "png", "an RGB PNG", e.to_string()))
    }
}

/// NumPy `.npy` v1.0, `<f4`, C order, shape (rows, cols).
pub fn encode_npy_f32(rows: usize, cols: usize, data: &[f32]) -> Result<Vec<u8>> {
    if rows * cols != data.len() {
        return Err(Error::Invalid(format!(
            "matrix {rows}x{cols} needs {} values, got {}",
            rows * cols,
            data.len()
        )));
    }
    let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    let unpadded = 10 + dict.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let hlen = dict.len() + pad + 1;
    let mut out = Vec::with_capacity(10 + hlen + data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(hlen as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.extend(std::iter::repeat_n(b' ', pad));
    out.push(b'\n');
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// Read what [`encode_npy_f32`] writes (also 1-D arrays, as (n, 1)).
pub fn decode_npy_f32(b: &[u8], path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let bad = |field: &str, exp: &str, found: String| Error::format(path, field, exp, found);
    if b.len() < 10 || &b[..6] != b"\x93NUMPY" || b[6] != 1 {
        return Err(bad("magic", "NumPy .npy v1", format!("{} bytes", b.len())));
    }
    let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = b
        .get(10..10 + hlen)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad("header", "a UTF-8 header", "truncated".into()))?;
    if !header.contains("'descr': '<f4'") || !header.contains("'fortran_order': False") {
        return Err(bad("header", "'<f4' in C order", header.trim().to_string()));
    }
    let shape_str = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad("shape", "a shape tuple", header.trim().to_string()))?;
    let dims: Vec<usize> = shape_str
        .split(',')
        .map(|s| s.trim())
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad("shape", "integers", shape_str.to_string()))?;
    let (rows, cols) = match dims.as_slice() {
        [n] => (*n, 1),
        [r, c] => (*r, *c),
        _ => return Err(bad("shape", "1-D or 2-D", shape_str.to_string())),
    };
    let body = &b[10 + hlen..];
    if body.len() != rows * cols * 4 {
        return Err(bad(
            "data",
            &format!("{} bytes", rows * cols * 4),
            format!("{} bytes", body.len()),
        ));
    }
    let data = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((rows, cols, data))
}

#[cfg(test)]
#[path = "cache_tests.rs"]
mod tests;
