#!/usr/bin/env bash
# The Table-4-style ablation on the redkitchen fragments rebuilt from the raw RGB-D frames
# (27 3DMatch + 10 3DLoMatch pairs): FPFH alone, the image branch alone (XFeat on oracle RGB),
# and the image branch fused with FPFH by concatenation, Noisy-OR and Noisy-AND; then the same
# with the built-in depth-shading generator (NOT a WFM) instead of the real RGB. Default
# parameters throughout (nothing tuned on these pairs). Results: studies/ablation/results/*.json and the
# table printed at the end (docs/ablation.md quotes it).
#
#   bash studies/ablation/ablation.sh [OUT_DIR]      # needs a release build and $CGENREG_DATA
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-studies/ablation/results}"
BIN="${CGENREG_BIN:-target/release/cgenreg}"
M=assets/manifests/redkitchen-rgbd.toml
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
mkdir -p "$OUT"

run() { # name, then bench options
    local name="$1"; shift
    echo "== $name: cgenreg bench $M $*" >&2
    "$BIN" bench "$M" "$@" --json "$OUT/$name.json" | tee "$OUT/$name.txt"
}

run fpfh-nn
run fpfh-mutual --selection mutual
for wfm in oracle builtin; do
    run "$wfm-image" --wfm "$wfm" --fusion image
    run "$wfm-concat" --wfm "$wfm" --fusion concat
    run "$wfm-noisy-or" --wfm "$wfm" --fusion noisy-or
    run "$wfm-noisy-and" --wfm "$wfm" --fusion noisy-and
done

"$BIN" table "$OUT"/fpfh-nn.json "$OUT"/fpfh-mutual.json \
    "$OUT"/oracle-{image,concat,noisy-or,noisy-and}.json \
    "$OUT"/builtin-{image,concat,noisy-or,noisy-and}.json | tee "$OUT/table.md"

# The same fused rows with each source's nearest target (the selection of the FPFH-nn row), so
# every row can be compared at equal selection.
for f in image concat noisy-or noisy-and; do
    run "oracle-$f-nn" --wfm oracle --fusion "$f" --selection nn
done
"$BIN" table "$OUT"/fpfh-nn.json "$OUT"/oracle-{image,concat,noisy-or,noisy-and}-nn.json | tee "$OUT/table-nn.md"
