//! CI smoke run of every fuzz target with the in-process mutation fuzzer (not
//! coverage-guided; the long runs use libFuzzer through `scripts/fuzz.sh`). Each target runs
//! for `CGENREG_FUZZ_SMOKE_S` seconds (default 0.75) from its generated seeds plus excerpts
//! of the staged data; any panic fails the test and prints the input (hex) and the seed.

// The harness the libFuzzer targets run, outside the library (only the readers' public API).
#[allow(dead_code)] // the libFuzzer entry points are not called here
#[path = "../../fuzz/src/targets.rs"]
mod ft;

#[test]
fn every_reader_survives_random_mutations() {
    let secs: f64 = std::env::var("CGENREG_FUZZ_SMOKE_S")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.75);
    let data = cgenreg::testing::test_data_root();
    let seed = 0x5eed_u64;
    let mut failures = Vec::new();
    for target in ft::all_targets() {
        let seeds: Vec<Vec<u8>> = ft::seeds(target, data.as_deref())
            .into_iter()
            .map(|(_, b)| b)
            .collect();
        assert!(!seeds.is_empty(), "{target}: no seeds");
        let rep = ft::fuzz(target, &seeds, secs, u64::MAX, seed);
        println!(
            "{target}: {} executions, {} accepted, {} crashes, slowest {:.1} ms",
            rep.executions,
            rep.accepted,
            rep.crashes.len(),
            rep.slowest_s * 1e3
        );
        assert!(rep.executions > 0, "{target}: nothing ran");
        for (input, msg) in rep.crashes.iter().take(1) {
            let hex: String = input
                .iter()
                .take(4096)
                .map(|b| format!("{b:02x}"))
                .collect();
            failures.push(format!(
                "{target} (seed {seed}): {msg}\n  input ({} bytes): {hex}",
                input.len()
            ));
        }
    }
    assert!(failures.is_empty(), "crashes:\n{}", failures.join("\n"));
}
