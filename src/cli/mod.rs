//! The `cgenreg` command line: the same pipeline as the GUI, for scripts, benchmarks and CI.

pub mod args;
mod bench;
mod cache;
mod diff;
mod generate;
#[cfg(feature = "gui")]
pub mod gui;
mod merge;
mod register;
mod slurm;
mod study;
mod table;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
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
    /// Two bench JSONs compared pair by pair: flipped successes, ΔRRE / ΔRTE, quadrants and
    /// the parameters that differ (`--json` for machine-readable output).
    Diff(diff::DiffArgs),
    /// List, verify or remove cache entries.
    Cache(cache::CacheArgs),
    /// Fill the stage cache with the expensive stages (depth video, generator, descriptors)
    /// of the selected pairs; sharded and resumable like `bench`.
    Generate(generate::GenerateArgs),
    /// Merge the shard outputs of one `bench`/`study`/`generate` run into one JSON and table.
    Merge(merge::MergeArgs),
    /// Pairs done / failed / missing per shard of a run, time per stage, projected cost.
    Status(merge::StatusArgs),
    /// Write (and with --submit, submit) a Slurm job array that runs a command in N shards.
    Slurm(slurm::SlurmArgs),
    /// One array task of a `cgenreg slurm` run (what its sbatch script runs).
    #[command(hide = true)]
    SlurmTask(slurm::SlurmTaskArgs),
    /// Open the inspector GUI (the default command; the bundled demo pair when no data is given).
    #[cfg(feature = "gui")]
    #[command(alias = "gui")]
    Inspect(gui::InspectArgs),
    /// Render the inspector headless (no X server) to a PNG.
    #[cfg(feature = "gui")]
    Screenshot(gui::ScreenshotArgs),
}

/// `inspect` changes only the saved settings its options name: it is told which were given.
fn with_named_options(c: Command, matches: &clap::ArgMatches) -> Command {
    match c {
        #[cfg(feature = "gui")]
        Command::Inspect(mut a) => {
            if let Some(("inspect", m)) = matches.subcommand() {
                a.named = gui::named_options(m);
            }
            Command::Inspect(a)
        }
        c => c,
    }
}

/// Runs one command (also what a Slurm array task runs, in-process).
pub fn run_command(c: Command) -> crate::Result<()> {
    match c {
        Command::Register(a) => register::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Cache(a) => cache::run(a),
        Command::Diff(a) => diff::run(a),
        Command::Study(a) => study::run(a),
        Command::Table(a) => table::run(a),
        Command::Generate(a) => generate::run(a),
        Command::Merge(a) => merge::run_merge(a),
        Command::Status(a) => merge::run_status(a),
        Command::Slurm(a) => slurm::run(a),
        Command::SlurmTask(a) => slurm::run_task(a),
        #[cfg(feature = "gui")]
        Command::Inspect(a) => gui::run_inspect(a),
        #[cfg(feature = "gui")]
        Command::Screenshot(a) => gui::run_screenshot(a),
    }
}

pub fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(c) => c,
        Err(e) => e.exit(),
    };
    let cli = Cli {
        command: cli.command.map(|c| with_named_options(c, &matches)),
    };
    let result = match cli.command {
        Some(c) => run_command(c),
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
