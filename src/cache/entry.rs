//! Writing an entry (`Cache::put`, [`NewEntry`]: a private folder, synced, renamed into
//! place) and reading a verified one ([`Entry`]), with the payload helpers.

use super::verify::check_name;
use super::{hash_bytes, Cache, CacheKey, FileRecord, Manifest, FORMAT, MANIFEST};
use crate::error::{Error, Result};
use crate::features::Features;
use serde::Serialize;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// A verified entry.
#[derive(Clone, Debug)]
pub struct Entry {
    pub dir: PathBuf,
    pub manifest: Manifest,
}

impl Cache {
    /// Start a new entry for `key`; nothing is visible until [`NewEntry::commit`].
    pub fn put(&self, key: &CacheKey, provenance: Value) -> Result<NewEntry> {
        let stage_dir = self.root.join(&key.stage);
        std::fs::create_dir_all(&stage_dir).map_err(|e| Error::io(&stage_dir, e))?;
        let tmp = stage_dir.join(format!(
            ".tmp-{}-{}",
            &key.hash[..16],
            crate::io::output::unique_suffix()
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
            .map_err(|e| Error::Encode(format!("serialising {name}: {e}")))?;
        self.add_bytes(name, &b)
    }

    pub fn add_f32_matrix(
        &mut self,
        name: &str,
        rows: usize,
        cols: usize,
        data: &[f32],
    ) -> Result<()> {
        if rows * cols != data.len() {
            return Err(Error::Shape(format!(
                "matrix {rows}x{cols} needs {} values, got {}",
                rows * cols,
                data.len()
            )));
        }
        self.add_bytes(name, &crate::io::npy::encode_npy_f32(&[rows, cols], data))
    }

    pub fn add_features(&mut self, name: &str, f: &Features) -> Result<()> {
        self.add_f32_matrix(name, f.len(), f.dim, &f.data)
    }

    pub fn add_png(&mut self, name: &str, img: &image::RgbImage) -> Result<()> {
        let mut buf = std::io::Cursor::new(Vec::new());
        img.write_to(&mut buf, image::ImageFormat::Png)
            .map_err(|e| Error::Encode(format!("encoding {name} as PNG: {e}")))?;
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
            .map_err(|e| Error::Encode(format!("serialising the manifest: {e}")))?;
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
        crate::io::npy::parse_npy_f32_matrix(&self.path(name), &self.read_bytes(name)?)
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
