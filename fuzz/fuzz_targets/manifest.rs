#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cgenreg::testing::fuzz_targets::run("manifest", data);
});
