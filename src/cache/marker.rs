//! The marker file that makes a directory a cgenreg cache: the commands that delete refuse a
//! directory without it.

use super::{Cache, FORMAT, MARKER};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// The marker file's content.
#[derive(Serialize, Deserialize)]
struct Marker {
    tool: String,
    format: u32,
    created_unix: u64,
}

impl Cache {
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
            .map_err(|e| Error::Encode(format!("serialising the cache marker: {e}")))?;
        crate::io::output::write_atomic(&self.root.join(MARKER), &b)?;
        Ok(true)
    }

    /// [`Error::NotACache`] unless the directory carries the marker: checked before a
    /// command deletes anything.
    pub(super) fn require_marker(&self) -> Result<()> {
        if self.is_marked() {
            Ok(())
        } else {
            Err(Error::NotACache {
                dir: self.root.clone(),
                marker: MARKER.into(),
            })
        }
    }
}
