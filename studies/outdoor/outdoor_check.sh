#!/usr/bin/env bash
# The outdoor check (docs/outdoor.md): the whole KITTI 07 ladder through the real manifest with
# no flags (the manifest's outdoor preset) must register at least 9 of 10 pairs at 5° / 2 m.
# Release build; the debug test suite guards the same ladder (`cargo test --test it kitti07_`:
# all 10 pairs).
#
#   CGENREG_DATA=/path/to/data studies/outdoor/outdoor_check.sh [OUT.json]
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$repo"
out="${1:-target/outdoor-kitti07.json}"
cargo build --release --bin cgenreg
target/release/cgenreg bench assets/manifests/kitti07.toml --no-cache --no-resume --json "$out"
python3 - "$out" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))["summary"]
n = sum(x["n"] for x in s)
ok = round(sum(x["recall"] * x["n"] for x in s))
print(f"KITTI 07: {ok}/{n} registered at RRE <= 5 deg, RTE <= 2 m")
sys.exit(0 if n == 10 and ok >= 9 else 1)
PY
