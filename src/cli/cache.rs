//! `cgenreg cache`: list, verify and remove entries of the content-addressed cache.

use crate::error::Result;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct CacheArgs {
    /// Cache directory (default: $CGENREG_CACHE or ~/.cache/cgenreg).
    #[arg(long)]
    pub dir: Option<PathBuf>,
}

pub fn run(_a: CacheArgs) -> Result<()> {
    Err(crate::Error::Invalid(
        "cgenreg cache: not implemented yet".into(),
    ))
}
