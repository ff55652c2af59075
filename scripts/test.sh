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
(nice -n 10 bash models/spinnet_prepare.sh && echo "== [$(($(date +%s) - start)) s] SpinNet ready" &&
  nice -n 10 bash scripts/test_python.sh --prepare && echo "== [$(($(date +%s) - start)) s] Python venv ready") \
  >"$prep_log" 2>&1 &
prep_pid=$!
# Test targets only: the crate has no doc tests, the binary has no tests of its own (it is
# built for the integration tests all the same), and the examples (built by a bare `cargo test`
# only to see that they compile; clippy --all-targets does that) cost a link each.
# The library's unit tests start the moment their binary is linked (scripts/lib/cargo_messages.py
# says when), on the core the integration tests' compile, the build's last unit, leaves free.
step "test build"
unit_log=target/test-unit.log
unit_exe=""
unit_pid=""
build_status=1
while IFS= read -r line; do
  case "$line" in
  "UNIT_TEST_EXE "*)
    unit_exe="${line#UNIT_TEST_EXE }"
    step "unit tests: started beside the rest of the build"
    (nice -n 5 "$unit_exe" >"$unit_log" 2>&1) &
    unit_pid=$!
    ;;
  "BUILD_STATUS "*) build_status="${line#BUILD_STATUS }" ;;
  *) printf '%s\n' "$line" ;;
  esac
done < <(
  cargo "${cargo_config[@]}" test --lib --tests --no-run --message-format=json-render-diagnostics 2>&1 |
    python3 scripts/lib/cargo_messages.py
  echo "BUILD_STATUS ${PIPESTATUS[0]}"
)
if [ "$build_status" != 0 ]; then status=$build_status; fi
step "waiting for the background preparation"
prep_status=0
wait "$prep_pid" || prep_status=$?
echo "== background preparation (SpinNet export, Python venv): exit $prep_status"
cat "$prep_log"
step "integration tests"
# The Python package's tests (pip install . gives it: built in the dev profile into target/,
# tested with pytest in a private virtual environment under target/) run beside the Rust
# integration tests, which leave part of the second core idle (a test waiting on a process or
# a daemon, the last tests of a binary). The extension build starts once `cargo test` has
# checked that its own targets are fresh (cargo holds the build folder's lock for that check,
# not while the tests run).
py_log=target/test-python.log
(sleep 15 && nice -n 10 bash scripts/test_python.sh --build && bash scripts/test_python.sh) \
  >"$py_log" 2>&1 &
py_pid=$!
cargo "${cargo_config[@]}" test --test '*' --no-fail-fast 2>&1 || status=$?
step "unit tests: results"
if [ -n "$unit_pid" ]; then
  unit_status=0
  wait "$unit_pid" || unit_status=$?
  cat "$unit_log"
  echo "== unit tests: exit $unit_status"
  if [ "$unit_status" != 0 ]; then status=$unit_status; fi
else
  echo "== unit tests: their binary was not built"
  status=1
fi
# Result tables are generated from the committed JSONs; a hand edit or a new JSON without a rerun fails.
step "result tables"
python3 scripts/tables.py --check || status=$?
# The narrower kernels on a wider CPU (same binary; CGENREG_SIMD caps the detected features):
# the fusion and SC2-PCR kernels must give the same bits at every width.
for isa in avx2 scalar; do
  step "CGENREG_SIMD=$isa: fusion, estimate and simd unit tests"
  if [ -n "$unit_exe" ]; then
    CGENREG_SIMD=$isa "$unit_exe" fusion:: estimate:: simd:: 2>&1 || status=$?
  fi
done
step "Python package: tests/python"
py_status=0
wait "$py_pid" || py_status=$?
cat "$py_log"
echo "== Python package: exit $py_status"
if [ "$py_status" != 0 ]; then status=$py_status; fi
step "done (exit $status)"
exit $status
