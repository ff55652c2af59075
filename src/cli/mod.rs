//! The `cgenreg` command line: the same pipeline as the GUI, for scripts, benchmarks and CI.
//!
//! Everything the commands print on stdout goes through [`outln!`] / [`out!`]: a closed pipe
//! (`cgenreg cache list | head -1`) or a full disk never panics. The first write error is
//! kept, later output is dropped, and the program ends with exit status 0 for a closed pipe
//! (what `head` users expect) or a clear error otherwise.

/// `println!` for the CLI: never panics on a stdout error (see the module docs).
macro_rules! outln {
    () => {
        $crate::cli::write_stdout(format_args!(""), true)
    };
    ($($t:tt)*) => {
        $crate::cli::write_stdout(format_args!($($t)*), true)
    };
}

/// `print!` for the CLI: never panics on a stdout error.
macro_rules! out {
    ($($t:tt)*) => {
        $crate::cli::write_stdout(format_args!($($t)*), false)
    };
}

pub mod args;
mod bench;
mod cache;
mod dataset;
mod diff;
mod generate;
#[cfg(feature = "gui")]
pub mod gui;
mod merge;
mod register;
mod score;
mod slurm;
mod study;
mod table;

pub use register::{register_with_options, PairInput, Registered};

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
    /// Write a manifest of a standard benchmark as downloaded (3DMatch / 3DLoMatch, KITTI).
    Dataset(dataset::DatasetArgs),
    /// Parameter studies over a manifest's pairs: RRE/RTE against K (figure 6) or per prompt
    /// category (figure 4).
    Study(study::StudyArgs),
    /// Several `bench --json` results as one table in the layout of the paper's Table 4.
    Table(table::TableArgs),
    /// Two bench JSONs compared pair by pair: flipped successes, ΔRRE / ΔRTE, quadrants and
    /// the parameters that differ (`--json` for machine-readable output).
    Diff(diff::DiffArgs),
    /// Another method's poses (JSON) scored as `bench` scores cgenreg's: the same tables, and a
    /// run file that `table` and `diff` compare with cgenreg's.
    Score(score::ScoreArgs),
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
#[cfg_attr(not(feature = "gui"), allow(unused_variables))]
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
        Command::Dataset(a) => dataset::run(a),
        Command::Diff(a) => diff::run(a),
        Command::Study(a) => study::run(a),
        Command::Table(a) => table::run(a),
        Command::Score(a) => score::run(a),
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

/// The first error writing to stdout (later output is dropped).
static STDOUT_ERROR: std::sync::Mutex<Option<std::io::Error>> = std::sync::Mutex::new(None);

/// Writes to stdout, keeping the first error instead of panicking.
pub(crate) fn write_stdout(args: std::fmt::Arguments, newline: bool) {
    use std::io::Write;
    let mut err = STDOUT_ERROR.lock().unwrap_or_else(|p| p.into_inner());
    if err.is_some() {
        return;
    }
    let mut o = std::io::stdout().lock();
    let r = o
        .write_fmt(args)
        .and_then(|()| if newline { o.write_all(b"\n") } else { Ok(()) });
    if let Err(e) = r {
        *err = Some(e);
    }
}

/// Flushes stdout and takes the first write error, if any.
fn stdout_error() -> Option<std::io::Error> {
    use std::io::Write;
    let mut err = STDOUT_ERROR.lock().unwrap_or_else(|p| p.into_inner());
    if err.is_none() {
        if let Err(e) = std::io::stdout().lock().flush() {
            *err = Some(e);
        }
    }
    err.take()
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
        crate::Error::Usage(text.trim_start_matches("error: ").trim().to_string())
    })
}

/// The settings `cgenreg register` runs with under `options` (e.g. `["--voxel", "0.1",
/// "--wfm", "builtin"]`): the same defaults, checks and errors; no cache is opened.
pub fn register_settings(options: &[String]) -> crate::Result<crate::pipeline::RegisterParams> {
    let a = parse_settings(options)?;
    let mut params = a.pipeline.to_params(a.image.wfm.is_some(), None);
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
    Ok(parse_settings(options)?
        .pipeline
        .to_params(image_branch, None))
}

/// The command line run in-process on `argv` (program name first); the exit code. What the
/// Python package's `cgenreg` console script runs.
pub fn main_with_args(argv: Vec<std::ffi::OsString>) -> i32 {
    let matches = match Cli::command().try_get_matches_from(argv) {
        Ok(m) => m,
        // --help / --version go through the same checked stdout as everything else
        Err(e) if !e.use_stderr() => {
            out!("{}", e.render());
            return match stdout_error() {
                Some(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
                    eprintln!("cgenreg: error: writing to stdout: {e}");
                    1
                }
                _ => 0,
            };
        }
        Err(e) => {
            let _ = e.print();
            return e.exit_code();
        }
    };
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return e.exit_code();
        }
    };
    let cli = Cli {
        command: cli.command.map(|c| with_named_options(c, &matches)),
    };
    let result = match cli.command {
        Some(c) => run_command(c),
        #[cfg(feature = "gui")]
        None => gui::run_inspect(gui::InspectArgs::default()),
        #[cfg(not(feature = "gui"))]
        None => Err(crate::Error::Usage(
            "built without the GUI: use a subcommand (see --help)".into(),
        )),
    };
    let out_err = stdout_error();
    match (result, out_err) {
        (Err(e), _) => {
            eprintln!("cgenreg: error: {e}");
            e.exit_status()
        }
        // The reader went away (`| head`): the output it wanted was written.
        (Ok(()), Some(e)) if e.kind() == std::io::ErrorKind::BrokenPipe => 0,
        (Ok(()), Some(e)) => {
            eprintln!("cgenreg: error: writing to stdout: {e}");
            1
        }
        (Ok(()), None) => 0,
    }
}

pub fn main() -> ExitCode {
    match main_with_args(std::env::args_os().collect()) {
        0 => ExitCode::SUCCESS,
        code => ExitCode::from(u8::try_from(code).unwrap_or(1)),
    }
}
