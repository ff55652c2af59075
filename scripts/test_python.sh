#!/usr/bin/env bash
# The Python package's tests (tests/python): the extension built by maturin in the dev profile
# into this repository's target folder (so the dependencies the Rust tests compiled are
# reused), installed into a private virtual environment under target/ (never the system's
# pip), then pytest. Needs the `cgenreg` binary of the Rust build (scripts/test.sh builds it
# first) to compare with. Exit status: pytest's (any failure, error or no test collected fails).
set -euo pipefail
cd "$(dirname "$0")/.."
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
venv="$PWD/target/pyvenv"
bash scripts/lib/venv_install.sh "$venv" "maturin==1.16.0" "numpy>=1.21" "pytest>=7" pandas
# `--prepare`: only the venv (scripts/test.sh makes it in the background while the tests build).
if [ "${1:-}" = "--prepare" ]; then exit 0; fi
# maturin reads pyproject.toml (manifest python/Cargo.toml); `develop` installs into $VIRTUAL_ENV.
# `--features gui`: the library with its default features, as the Rust build above compiled it,
# so that build's artifacts are reused (without the GUI, crates such as `half` get other
# features and the ONNX stack is compiled a second time); the wheel `pip install .` builds
# differs only in carrying no inspector (tested by monkeypatching the extension's HAS_GUI).
SECONDS=0
# CGENREG_CARGO_CONFIG: the cargo settings (a `--config` value: a file or KEY=VALUE) scripts/test.sh
# built with (under CI), so the library compiled there is reused.
config=()
if [ -n "${CGENREG_CARGO_CONFIG:-}" ]; then config=(--config "$CGENREG_CARGO_CONFIG"); fi
VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH" "$venv/bin/maturin" develop --quiet --features gui "${config[@]}"
echo "test_python: extension built and installed in ${SECONDS} s"
# `--build`: only the venv and the extension (scripts/test.sh builds it in the background while
# the Rust tests run).
if [ "${1:-}" = "--build" ]; then exit 0; fi
CGENREG_TEST_BIN="${CGENREG_TEST_BIN:-$PWD/target/debug/cgenreg}" \
  "$venv/bin/python" -m pytest -q -p no:cacheprovider tests/python "$@"
