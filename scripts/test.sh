#!/usr/bin/env bash
# The one command that passes the tests on a fresh machine (README, .ci/run).
set -euo pipefail
cd "$(dirname "$0")/.."
# Each step's start, in seconds since this script began (what a CI log needs to see where the time goes).
start=$(date +%s)
step() { echo "== [$(($(date +%s) - start)) s] $*"; }
step "setup"
CGENREG_SETUP_SKIP_SPINNET=1 bash scripts/setup.sh
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
# A clean clone builds everything once: incremental compilation only adds its bookkeeping there.
# The crate's own settings for such a build (one codegen unit, no line tables) are in
# .ci/cargo-config.toml, not in Cargo.toml, where an edit-and-rebuild loop would pay for them
# (docs/development.md). Every cargo call below, and the Python extension's build
# (scripts/test_python.sh reads CGENREG_CARGO_CONFIG), passes the same file, or the library
# would be compiled again.
cargo_config=()
if [ "${CI:-}" = "true" ]; then
  export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
  export CGENREG_CARGO_CONFIG="${CGENREG_CARGO_CONFIG-$PWD/.ci/cargo-config.toml}"
fi
if [ -n "${CGENREG_CARGO_CONFIG:-}" ]; then cargo_config=(--config "$CGENREG_CARGO_CONFIG"); fi
status=0
# What only needs the network and a disk (SpinNet's export: a 3 GB torch download under CI; the
# Python tests' venv) is made in the background while the tests compile on every core.
mkdir -p target
prep_log=target/test-prepare.log
# At a lower priority: the build is the critical path, the download mostly waits on the network.
(nice -n 10 bash scripts/spinnet_prepare.sh && echo "== [$(($(date +%s) - start)) s] SpinNet ready" &&
  nice -n 10 bash scripts/test_python.sh --prepare && echo "== [$(($(date +%s) - start)) s] Python venv ready") \
  >"$prep_log" 2>&1 &
prep_pid=$!
# Test targets only: the crate has no doc tests, the binary has no tests of its own (it is
# built for the integration tests all the same), and the examples (built by a bare `cargo test`
# only to see that they compile; clippy --all-targets does that) cost a link each.
step "test build"
cargo "${cargo_config[@]}" test --lib --tests --no-run 2>&1 || status=$?
step "waiting for the background preparation"
prep_status=0
wait "$prep_pid" || prep_status=$?
echo "== background preparation (SpinNet export, Python venv): exit $prep_status"
cat "$prep_log"
step "tests"
# The Python extension (the binding crate and its link: mostly one core) builds in the background,
# at a lower priority, while the Rust tests run and leave part of the second core idle; the Python
# step below then finds it built. It starts once `cargo test` has checked that its own targets are
# fresh (cargo holds the build folder's lock for that check, not while the tests run).
py_build_log=target/test-python-build.log
(sleep 15 && nice -n 10 bash scripts/test_python.sh --build) >"$py_build_log" 2>&1 &
py_build_pid=$!
cargo "${cargo_config[@]}" test --lib --tests --no-fail-fast 2>&1 || status=$?
# Result tables are generated from the committed JSONs; a hand edit or a new JSON without a rerun fails.
step "result tables"
python3 scripts/tables.py --check || status=$?
# The narrower kernels on a wider CPU (same binary; CGENREG_SIMD caps the detected features):
# the fusion and SC2-PCR kernels must give the same bits at every width.
for isa in avx2 scalar; do
  step "CGENREG_SIMD=$isa: fusion, estimate and simd unit tests"
  CGENREG_SIMD=$isa cargo "${cargo_config[@]}" test --lib --no-fail-fast -- fusion:: estimate:: simd:: 2>&1 || status=$?
done
# The Python package (pip install . gives it): built in the dev profile into target/, tested
# with pytest in a private virtual environment under target/.
step "Python package: tests/python"
py_build_status=0
wait "$py_build_pid" || py_build_status=$?
echo "== background Python extension build: exit $py_build_status"
cat "$py_build_log"
bash scripts/test_python.sh 2>&1 || status=$?
step "done (exit $status)"
exit $status
