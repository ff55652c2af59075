//! A generation run's output (`cgenreg generate --json`, and `cgenreg merge` of its shards):
//! the run file's header and records, with the manifest and parameters on top as every run
//! output has them.

use crate::error::{Error, Result};
use crate::pipeline::shard::RunFile;
use serde_json::json;

/// Generate output bytes for a run file.
pub fn generate_json(f: &RunFile) -> Result<Vec<u8>> {
    let v = json!({
        "manifest": f.run.identity.manifest,
        "params": f.run.identity.params,
        "run": f.run,
        "records": f.records,
    });
    serde_json::to_vec_pretty(&v).map_err(|e| Error::Encode(format!("serialising: {e}")))
}
