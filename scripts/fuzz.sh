#!/usr/bin/env bash
# Fuzz one reader (or all) for a given time: scripts/fuzz.sh TARGET|all SECONDS
#
# Engines (FUZZ_ENGINE):
#   libfuzzer (default): the coverage-guided libFuzzer targets of fuzz/, built on the stable
#       toolchain with sanitizer-coverage instrumentation (no ASan: the readers are safe Rust;
#       debug assertions and overflow checks are on), g++ builds libFuzzer itself.
#   mutation: the in-process mutation fuzzer (examples/fuzz.rs; not coverage-guided), for
#       machines without a C++ compiler.
# The seed corpus is rebuilt at run time into fuzz/corpus/TARGET from generated seeds and
# small excerpts of $CGENREG_DATA (default ../shared/data); the data set is never copied.
# Crashes go to fuzz/artifacts/TARGET/. Prints one line per target:
#   TARGET engine=E executions=N exec_per_s=R cov=C ft=F corpus=U peak_rss_mb=M crashes=K seconds=S rc=RC
# (cov/ft: libFuzzer's edge coverage and feature counts at the end of the run).
# Exits 1 if any target crashed. Extra libFuzzer flags: FUZZ_FLAGS="-max_len=65536 ...";
# FUZZ_RUNS=N stops a target after N executions (or SECONDS, whichever comes first);
# FUZZ_BUILD=0 skips the build; FUZZ_TIMEOUT=S (default 10) is libFuzzer's per-input timeout: a
# run stopped with SIGSTOP counts the stop against the input being run, so a long background run
# that other work pauses needs a timeout above the longest pause (session 11: two spurious
# "timeouts" of 41 s, each input re-run in 1-20 ms).
# Needs a C++ compiler for libFuzzer (scripts/setup.sh installs g++ when it is missing).
set -euo pipefail
cd "$(dirname "$0")/.."
TARGET=${1:?usage: scripts/fuzz.sh TARGET|all SECONDS}
SECS=${2:?usage: scripts/fuzz.sh TARGET|all SECONDS}
ENGINE=${FUZZ_ENGINE:-libfuzzer}
export CGENREG_DATA=${CGENREG_DATA:-$(cd .. && pwd)/shared/data}
ALL="ply pcd lzf npy npz pickle pth kitti xyz gtlog depth_png intrinsics pose manifest cosmos_jsonl mp4 h264"
if [ "$TARGET" = all ]; then TARGETS=$ALL; else TARGETS=$TARGET; fi
HOST=$(rustc -vV | sed -n 's/^host: //p')
status=0

if [ "$ENGINE" = libfuzzer ]; then
  export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cdebug-assertions -Coverflow-checks"
  # --target keeps the instrumentation off build scripts and proc macros.
  command -v "${CXX:-c++}" >/dev/null 2>&1 || {
    echo "fuzz.sh: no C++ compiler (${CXX:-c++}) for libFuzzer; run scripts/setup.sh or use FUZZ_ENGINE=mutation" >&2
    exit 2
  }
  # FUZZ_BUILD=0 reuses the binaries already in fuzz/target (a long run while sources change).
  [ "${FUZZ_BUILD:-1}" = 0 ] || cargo build --release --manifest-path fuzz/Cargo.toml --target "$HOST" --bins
  BIN=fuzz/target/$HOST/release
  for t in $TARGETS; do
    mkdir -p "fuzz/corpus/$t" "fuzz/artifacts/$t"
    "$BIN/seeds" "$t" "fuzz/corpus/$t" >/dev/null
    log="fuzz/artifacts/$t/last.log"
    set +e
    "$BIN/$t" -max_total_time="$SECS" -timeout="${FUZZ_TIMEOUT:-10}" -rss_limit_mb=2048 -max_len=1048576 \
      -print_final_stats=1 -artifact_prefix="fuzz/artifacts/$t/" ${FUZZ_RUNS:+-runs=$FUZZ_RUNS} \
      ${FUZZ_FLAGS:-} "fuzz/corpus/$t" >"$log" 2>&1
    rc=$?
    set -e
    stat() { sed -n "s/^stat::$1: *//p" "$log" | tail -1; }
    runs=$(stat number_of_executed_units)
    rate=$(stat average_exec_per_sec)
    rss=$(stat peak_rss_mb)
    # The last status line: "#N DONE cov: C ft: F corp: U/..." (or the last pulse/NEW line).
    last=$(grep -E '^#[0-9]+' "$log" | tail -1)
    cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
    ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
    corp=$(sed -n 's/.* corp: \([0-9]*\).*/\1/p' <<<"$last")
    crashes=$(ls "fuzz/artifacts/$t" | grep -c -E '^(crash|timeout|oom|leak)-' || true)
    echo "$t engine=libfuzzer executions=${runs:-?} exec_per_s=${rate:-?} cov=${cov:-?} ft=${ft:-?}" \
      "corpus=${corp:-?} peak_rss_mb=${rss:-?} crashes=$crashes seconds=$SECS rc=$rc"
    if [ "$rc" -ne 0 ] || [ "$crashes" -ne 0 ]; then status=1; tail -30 "$log"; fi
  done
else
  cargo build --release --example fuzz
  for t in $TARGETS; do
    set +e
    target/release/examples/fuzz run "$t" "$SECS" --crashes "fuzz/artifacts/$t"
    rc=$?
    set -e
    [ "$rc" -ne 0 ] && status=1
  done
fi
exit $status
