//! `cgenreg diff A.json B.json`: two bench runs compared pair by pair (flipped successes,
//! ΔRRE / ΔRTE, success quadrants, parameters that differ); see `report::compare`.

use crate::error::{Error, Result};
use crate::report::compare::{compare, load_bench_run, table};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct DiffArgs {
    /// Run A (`cgenreg bench --json` or `cgenreg merge` output).
    pub a: PathBuf,
    /// Run B; deltas are B minus A.
    pub b: PathBuf,
    /// Print the comparison as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: DiffArgs) -> Result<()> {
    let c = compare(&load_bench_run(&a.a)?, &load_bench_run(&a.b)?);
    if a.json {
        let s = serde_json::to_string_pretty(&c)
            .map_err(|e| Error::Encode(format!("serialising the comparison: {e}")))?;
        outln!("{s}");
    } else {
        out!("{}", table(&c));
    }
    Ok(())
}
