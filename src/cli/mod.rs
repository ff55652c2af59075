//! The `cgenreg` command line: the same pipeline as the GUI, for scripts, benchmarks and CI.

mod args;
mod bench;
mod cache;
mod diff;
mod generate;
#[cfg(feature = "gui")]
mod gui;
mod merge;
mod register;
mod slurm;
mod study;
mod table;

pub use register::{register_with_options, PairInput, Registered};

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

/// `cgenreg register`'s pipeline and image-branch options alone (no program name, no pair):
/// what the Python package parses its keyword arguments with, so that they mean exactly what
/// the command line's options mean (names, defaults, checks and messages).
#[derive(Parser, Debug)]
#[command(name = "cgenreg register", no_binary_name = true)]
struct SettingsArgs {
    #[command(flatten)]
    pipeline: args::PipelineArgs,
    #[command(flatten)]
    image: args::ImageArgs,
}

fn parse_settings(options: &[String]) -> crate::Result<SettingsArgs> {
    SettingsArgs::try_parse_from(options).map_err(|e| {
        // clap's own text without its usage footer: the option, the value and what it takes
        let text = e.to_string();
        let text = text.split("\n\n").next().unwrap_or(&text);
        crate::Error::Invalid(text.trim_start_matches("error: ").trim().to_string())
    })
}

/// The settings `cgenreg register` runs with under `options` (e.g. `["--voxel", "0.1",
/// "--wfm", "builtin"]`): the same defaults, checks and errors; no cache is opened.
pub fn register_settings(options: &[String]) -> crate::Result<crate::pipeline::RegisterParams> {
    let a = parse_settings(options)?;
    let mut params = a.pipeline.to_params(a.image.wfm.is_some());
    params.image = a.image.to_image_params()?;
    Ok(params)
}

/// [`register_settings`] for the fusion stage alone: the default selection is the fused one
/// (mutual nearest neighbours) when `image_branch`, row nearest neighbours otherwise, as in
/// `cgenreg register`; no cache is opened.
pub fn fusion_settings(
    options: &[String],
    image_branch: bool,
) -> crate::Result<crate::pipeline::RegisterParams> {
    Ok(parse_settings(options)?.pipeline.to_params(image_branch))
}

/// The command line run in-process on `argv` (program name first); the exit code. What the
/// Python package's `cgenreg` console script runs.
pub fn main_with_args(argv: Vec<std::ffi::OsString>) -> i32 {
    let cli = match Cli::try_parse_from(argv) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return e.exit_code();
        }
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
        Ok(()) => 0,
        Err(e) => {
            eprintln!("cgenreg: error: {e}");
            1
        }
    }
}

pub fn main() -> ExitCode {
    match main_with_args(std::env::args_os().collect()) {
        0 => ExitCode::SUCCESS,
        code => ExitCode::from(u8::try_from(code).unwrap_or(1)),
    }
}
