//! `cgenreg inspect` and `cgenreg screenshot`.

use crate::error::Result;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug, Default)]
pub struct InspectArgs {
    /// Dataset manifest to open (default: the bundled demo pair).
    #[arg(long)]
    pub manifest: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct ScreenshotArgs {
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run_inspect(_a: InspectArgs) -> Result<()> {
    Err(crate::Error::Invalid(
        "cgenreg inspect: not implemented yet".into(),
    ))
}

pub fn run_screenshot(_a: ScreenshotArgs) -> Result<()> {
    Err(crate::Error::Invalid(
        "cgenreg screenshot: not implemented yet".into(),
    ))
}
