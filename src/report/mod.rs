//! Run outputs written and read back: each command's output format (`bench`, `study`,
//! `generate`), the typed rows of a `cgenreg bench --json` output and their comparison
//! (`cgenreg diff`, the inspector's Compare tab). A floor above `pipeline` (a run's header holds
//! its `RegisterParams`), below the CLI and the app.

pub mod bench_file;
pub mod compare;
pub mod generate_file;
pub mod labels;
pub mod study_file;

use crate::error::{Error, Result};
use crate::pipeline::shard::RunFile;

/// A run file's bytes in the format of the command that made it (`bench`, `study k|prompt`,
/// `generate`): what each command writes after every pair, and what `merge` writes.
pub fn run_output_bytes(f: &RunFile) -> Result<Vec<u8>> {
    match f.run.identity.command.as_str() {
        "bench" => bench_file::bench_json(f),
        c if c.starts_with("study") => study_file::study_json(f),
        "generate" => generate_file::generate_json(f),
        c => Err(Error::Invalid(format!(
            "unknown command {c:?} in a run file"
        ))),
    }
}
