//! The fuzz harness the targets in `fuzz_targets/` and the `seeds` tool call. The same file
//! is included by the main crate's `fuzz` example and its CI smoke test.

pub mod targets;
