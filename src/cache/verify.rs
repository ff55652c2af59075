//! What is an entry, and whether it is intact: file and folder names, ownership (what the
//! commands may delete) and the re-hash of every file against the manifest.

use super::{hash_file, Manifest, FORMAT, MANIFEST};
use crate::error::{Error, Result};
use serde::Deserialize;
use std::path::Path;

pub(super) fn check_name(name: &str) -> Result<()> {
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
pub(super) fn is_entry_name(name: &str) -> bool {
    name.len() == 64
        && name
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Whether `name` can be a stage folder's name (as [`CacheKey::new`] allows).
pub(super) fn is_stage_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
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
pub(super) fn verify_dir(dir: &Path) -> std::result::Result<Manifest, String> {
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
