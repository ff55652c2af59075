//! The `cgenreg` command line: the same pipeline as the GUI, for scripts, benchmarks and CI.

mod args;
mod bench;
mod register;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(name = "cgenreg", version, about = "Training-free point-cloud registration by C-GenReg")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Register one pair (two cloud files, or a pair of a dataset manifest).
    Register(register::RegisterArgs),
    /// Register every pair of a dataset manifest and print the paper-style table.
    Bench(bench::BenchArgs),
}

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Register(a) => register::run(a),
        Command::Bench(a) => bench::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cgenreg: error: {e}");
            ExitCode::FAILURE
        }
    }
}
