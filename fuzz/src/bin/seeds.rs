//! Write the seed corpus of one fuzz target (generated seeds plus small excerpts of the
//! staged data at `$CGENREG_DATA`): `seeds TARGET DIR`.

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [target, dir] = &args[..] else {
        eprintln!("usage: seeds TARGET DIR");
        std::process::exit(64);
    };
    let data = std::env::var_os("CGENREG_DATA")
        .map(std::path::PathBuf::from)
        .filter(|p| p.is_dir());
    std::fs::create_dir_all(dir).expect("create the corpus folder");
    let seeds = cgenreg::io::fuzz_targets::seeds(target, data.as_deref());
    for (name, bytes) in &seeds {
        std::fs::write(std::path::Path::new(dir).join(name), bytes).expect("write a seed");
    }
    println!("{target}: {} seeds in {dir}", seeds.len());
}
