//! Write the seed corpus of one fuzz target (generated seeds plus small excerpts of the
//! staged data at `$CGENREG_DATA`): `seeds TARGET DIR`.
//!
//! Built with the targets' sanitizer-coverage flags, so it must link libFuzzer (which
//! defines the `__sanitizer_cov_*` callbacks); libFuzzer's `main` runs the `init` block
//! first, which writes the seeds and exits before any fuzzing starts.
#![no_main]

fn write_seeds() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [target, dir] = &args[..] else {
        eprintln!("usage: seeds TARGET DIR");
        std::process::exit(64);
    };
    let data = std::env::var_os("CGENREG_DATA")
        .map(std::path::PathBuf::from)
        .filter(|p| p.is_dir());
    if let Err(e) = std::fs::create_dir_all(dir) {
        eprintln!("seeds: cannot create {dir}: {e}");
        std::process::exit(1);
    }
    let seeds = cgenreg_fuzz::targets::seeds(target, data.as_deref());
    for (name, bytes) in &seeds {
        let p = std::path::Path::new(dir).join(name);
        if let Err(e) = std::fs::write(&p, bytes) {
            eprintln!("seeds: cannot write {}: {e}", p.display());
            std::process::exit(1);
        }
    }
    // How many the reader accepts (a seed it refuses still gives the fuzzer a start).
    let refused: Vec<&str> = seeds
        .iter()
        .filter(|(_, b)| !cgenreg_fuzz::targets::run(target, b))
        .map(|(n, _)| n.as_str())
        .collect();
    println!(
        "{target}: {} seeds in {dir} ({} accepted; refused: {refused:?})",
        seeds.len(),
        seeds.len() - refused.len()
    );
    std::process::exit(0)
}

libfuzzer_sys::fuzz_target!(init: write_seeds(), |_data: &[u8]| {});
