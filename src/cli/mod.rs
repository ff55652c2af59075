//! The `cgenreg` command line: the same pipeline as the GUI, for scripts, benchmarks and CI.

mod args;
mod bench;
mod cache;
#[cfg(feature = "gui")]
mod gui;
mod register;
mod study;
mod table;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "cgenreg",
    version,
    about = "Training-free point-cloud registration by C-GenReg"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Register one pair (two cloud files, or a pair of a dataset manifest).
    Register(register::RegisterArgs),
    /// Register every pair of a dataset manifest and print the paper-style table.
    Bench(bench::BenchArgs),
    /// Parameter studies over a manifest's pairs: RRE/RTE against K (figure 6) or per prompt
    /// category (figure 4).
    Study(study::StudyArgs),
    /// Several `bench --json` results as one table in the layout of the paper's Table 4.
    Table(table::TableArgs),
    /// List, verify or remove cache entries.
    Cache(cache::CacheArgs),
    /// Open the inspector GUI (the default command; the bundled demo pair when no data is given).
    #[cfg(feature = "gui")]
    Inspect(gui::InspectArgs),
    /// Render the inspector headless (no X server) to a PNG.
    #[cfg(feature = "gui")]
    Screenshot(gui::ScreenshotArgs),
}

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Register(a)) => register::run(a),
        Some(Command::Bench(a)) => bench::run(a),
        Some(Command::Cache(a)) => cache::run(a),
        Some(Command::Study(a)) => study::run(a),
        Some(Command::Table(a)) => table::run(a),
        #[cfg(feature = "gui")]
        Some(Command::Inspect(a)) => gui::run_inspect(a),
        #[cfg(feature = "gui")]
        Some(Command::Screenshot(a)) => gui::run_screenshot(a),
        #[cfg(feature = "gui")]
        None => gui::run_inspect(gui::InspectArgs::default()),
        #[cfg(not(feature = "gui"))]
        None => Err(crate::Error::Invalid(
            "built without the GUI: use a subcommand (see --help)".into(),
        )),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cgenreg: error: {e}");
            ExitCode::FAILURE
        }
    }
}
