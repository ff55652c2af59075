fn main() -> std::process::ExitCode {
    cgenreg::cli::main()
}
