// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
fn main() {}
