#!/usr/bin/env bash
# The one command that passes the tests on a fresh machine (README, .ci/run).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
cargo test --no-fail-fast 2>&1
