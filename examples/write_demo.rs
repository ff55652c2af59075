//! Render the synthetic demo scene: `cargo run --example write_demo -- <dir> [width height frames]`.

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
fn main() -> cgenreg::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = std::path::PathBuf::from(args.first().map(String::as_str).unwrap_or("assets/demo"));
    let mut p = cgenreg::synth::DemoParams::default();
    if args.len() >= 4 {
        let num = |i: usize| {
            args[i]
                .parse::<u32>()
                .map_err(|e| cgenreg::Error::Invalid(format!("argument {i}: {e}")))
        };
        p.width = num(1)?;
        p.height = num(2)?;
        p.frames = num(3)? as usize;
    }
    let t = std::time::Instant::now();
    let m = cgenreg::synth::write_demo(&dir, &p)?;
    println!("wrote {} in {:?}", m.display(), t.elapsed());
    Ok(())
}
