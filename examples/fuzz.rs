//! The in-process mutation fuzzer (stable toolchain; not coverage-guided) and the seed-corpus
//! builder shared with the libFuzzer targets in `fuzz/`. See `docs/reliability.md`.
//!
//! ```text
//! cargo run --release --example fuzz -- seeds TARGET DIR     # write TARGET's seeds to DIR
//! cargo run --release --example fuzz -- run TARGET SECONDS [--corpus DIR] [--seed N]
//!                                        [--crashes DIR] [--timeout S]
//! cargo run --release --example fuzz -- list
//! ```
//!
//! Seeds come from `$CGENREG_DATA` (or `../shared/data`) when present, re-encoded small.
//! `run` prints one line `TARGET executions=N accepted=N crashes=N slowest_ms=X`, writes each
//! crashing input to the crash folder (default `fuzz/artifacts/TARGET`) and exits 1 on a
//! crash, 2 on a hang (an execution over `--timeout` seconds, default 10).

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

// The harness the libFuzzer targets run, outside the library (only the readers' public API).
#[allow(dead_code)]
#[path = "../fuzz/src/targets.rs"]
mod ft;
use std::path::{Path, PathBuf};

fn data_root() -> Option<PathBuf> {
    std::env::var_os("CGENREG_DATA")
        .map(PathBuf::from)
        .or_else(|| Some(PathBuf::from("../shared/data")))
        .filter(|p| p.is_dir())
}

fn usage() -> ! {
    eprintln!("usage: fuzz seeds TARGET DIR | fuzz run TARGET SECONDS [--corpus DIR] [--seed N] [--crashes DIR] [--timeout S] | fuzz list");
    std::process::exit(64)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("list") => {
            for t in ft::all_targets() {
                println!("{t}");
            }
        }
        Some("seeds") if args.len() == 3 => {
            let dir = Path::new(&args[2]);
            std::fs::create_dir_all(dir).expect("create the corpus folder");
            let s = ft::seeds(&args[1], data_root().as_deref());
            for (name, bytes) in &s {
                std::fs::write(dir.join(name), bytes).expect("write a seed");
            }
            println!("{}: {} seeds in {}", args[1], s.len(), dir.display());
        }
        Some("run") if args.len() >= 3 => {
            let target = args[1].clone();
            let secs: f64 = args[2].parse().unwrap_or_else(|_| usage());
            let mut corpus = None;
            let mut seed = 1u64;
            let mut crashes = PathBuf::from("fuzz/artifacts").join(&target);
            let mut timeout = 10.0f64;
            let mut it = args[3..].iter();
            while let Some(a) = it.next() {
                let v = it.next().unwrap_or_else(|| usage());
                match a.as_str() {
                    "--corpus" => corpus = Some(PathBuf::from(v)),
                    "--seed" => seed = v.parse().unwrap_or_else(|_| usage()),
                    "--crashes" => crashes = PathBuf::from(v),
                    "--timeout" => timeout = v.parse().unwrap_or_else(|_| usage()),
                    _ => usage(),
                }
            }
            let mut seeds: Vec<Vec<u8>> = ft::seeds(&target, data_root().as_deref())
                .into_iter()
                .map(|(_, b)| b)
                .collect();
            if let Some(dir) = &corpus {
                if let Ok(rd) = std::fs::read_dir(dir) {
                    for e in rd.flatten() {
                        if let Ok(b) = std::fs::read(e.path()) {
                            seeds.push(b);
                        }
                    }
                }
            }
            // Watchdog: an execution that runs past the timeout is a hang.
            {
                let crashes = crashes.clone();
                let target = target.clone();
                std::thread::spawn(move || loop {
                    std::thread::sleep(std::time::Duration::from_millis(250));
                    let cur = ft::CURRENT.lock().ok().and_then(|c| c.clone());
                    if let Some((t, input)) = cur {
                        if t.elapsed().as_secs_f64() > timeout {
                            let _ = std::fs::create_dir_all(&crashes);
                            let p = crashes.join(format!("hang-{:016x}", hash(&input)));
                            let _ = std::fs::write(&p, &input);
                            println!(
                                "{target} HANG: an execution ran past {timeout} s; input saved to {}",
                                p.display()
                            );
                            std::process::exit(2);
                        }
                    }
                });
            }
            let rep = ft::fuzz(&target, &seeds, secs, u64::MAX, seed);
            for (input, msg) in &rep.crashes {
                let _ = std::fs::create_dir_all(&crashes);
                let p = crashes.join(format!("crash-{:016x}", hash(input)));
                let _ = std::fs::write(&p, input);
                println!("{target} CRASH: {msg}; input saved to {}", p.display());
            }
            println!(
                "{target} executions={} accepted={} crashes={} slowest_ms={:.1} seconds={secs}",
                rep.executions,
                rep.accepted,
                rep.crashes.len(),
                rep.slowest_s * 1e3
            );
            if !rep.crashes.is_empty() {
                std::process::exit(1);
            }
        }
        _ => usage(),
    }
}

/// FNV-1a, for crash file names.
fn hash(b: &[u8]) -> u64 {
    b.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &x| {
        (h ^ x as u64).wrapping_mul(0x100_0000_01b3)
    })
}
