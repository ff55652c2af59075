//! The `cgenreg` command line.
pub fn main() -> std::process::ExitCode {
    eprintln!("cgenreg: in progress");
    std::process::ExitCode::FAILURE
}
