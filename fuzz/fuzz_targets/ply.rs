#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    cgenreg_fuzz::targets::run("ply", data);
});
