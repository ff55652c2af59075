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
//! f32 matrices and [`Features`](crate::features::Features) as `.npy` (little-endian f32, C
//! order, 2-D, NPY v1, written and read by `crate::io::npy`), images as PNG, JSON as
//! pretty-printed UTF-8.
//!
//! Files: this one holds the [`Cache`] (open, get, list, verify, remove) and the manifest
//! types; `key.rs` the [`CacheKey`] and content hashes; `entry.rs` writing ([`NewEntry`]) and
//! reading ([`Entry`]) an entry; `verify.rs` entry names, ownership and re-hashing;
//! `marker.rs` the marker file.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::{Path, PathBuf};

mod entry;
mod key;
mod marker;
mod verify;

pub use entry::{Entry, NewEntry};
pub use key::{canonical, hash_bytes, hash_file, CacheKey};
pub use verify::owned_entry;
use verify::{is_entry_name, is_stage_name, verify_dir};

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
            // A read-only or full cache root: every store will fail with a warning (the run
            // goes on without caching), so the marker is a warning too, not the run's end.
            if let Err(e) = c.init() {
                eprintln!(
                    "warning: cache {}: could not write the marker file: {e} (the run goes on; \
                     results cannot be stored)",
                    c.root.display()
                );
            }
        }
        Ok(c)
    }

    /// A cache at `dir` as it is: nothing is created (the cache commands use this; a missing
    /// directory lists as empty).
    pub fn at(dir: impl Into<PathBuf>) -> Cache {
        Cache { root: dir.into() }
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
            n => Err(Error::Usage(format!(
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
        let trash = parent.join(format!(".trash-{}", crate::io::output::unique_suffix()));
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

#[cfg(test)]
mod tests;
