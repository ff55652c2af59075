#!/usr/bin/env bash
# The development-set sweep of docs/ablation.md ("Evaluation protocol"): the values the paper
# and the reference do not fix for this project's VFMs and FPFH, chosen on
# assets/manifests/redkitchen-dev.toml (never on the evaluated redkitchen-rgbd pairs).
# One `cgenreg bench ... --json` per row, then `cgenreg table`.
#
#   bash studies/dev-sweep/devset_sweep.sh [OUT_DIR] [VFM]     # VFM: xfeat (default) | alike | disk
#   (alike / disk: the --dense-stride rows, STRIDES="1 4" by default)
#
# Env: CGENREG_BIN (default target/debug/cgenreg), CGENREG_CACHE (stage cache; default
# ~/.cache/cgenreg-devset), CGENREG_DATA. Rows already in OUT_DIR are kept (bench resumes a
# JSON written with the same parameters and binary).
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-studies/dev-sweep/results/dev}"
VFM="${2:-xfeat}"
BIN="${CGENREG_BIN:-target/debug/cgenreg}"
CACHE="${CGENREG_CACHE:-$HOME/.cache/cgenreg-devset}"
M=assets/manifests/redkitchen-dev.toml
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
mkdir -p "$OUT"

run() { # name, then bench options
    local name="$1"; shift
    echo "== $name: cgenreg bench $M $* --cache-dir $CACHE --json $OUT/$name.json" >&2
    nice -n 10 "$BIN" bench "$M" "$@" --cache-dir "$CACHE" --json "$OUT/$name.json" > "$OUT/$name.txt"
}

if [ "$VFM" = xfeat ]; then
    run fpfh-nn --selection nn
    run fpfh-mutual --selection mutual
fi
# Dense per-pixel VFMs (alike, disk): the cell size they are read through at a lifted pixel
# (--dense-stride: 1 = the pixel of the full-resolution map, 4 = bilinear between 4-px cell
# centres, the pre-session-11 path), at the values frozen with XFeat (Noisy-AND, mutual NN,
# tau 0.1 / 0.1), oracle frames. FPFH-NN of the same binary as the reference row.
if [ "$VFM" != xfeat ]; then
    run fpfh-nn --selection nn
    for s in ${STRIDES:-1 4}; do
        run "$VFM-oracle-noisy-and-mutual-tau0.1-stride$s" --wfm oracle --vfm "$VFM" \
            --fusion noisy-and --selection mutual --tau-img 0.1 --dense-stride "$s"
    done
    "$BIN" table "$OUT"/fpfh-nn.json "$OUT/$VFM"-*.json | tee "$OUT/table-$VFM.md"
    exit 0
fi
# Selection x image temperature, Noisy-AND, oracle frames. The rows run for docs/ablation.md
# (2026-12-02, debug build, 2-core machine shared with five other jobs): NN at tau-img 0.05
# and 0.1, mutual NN at 0.1. FULL=1 runs the whole grid (tau-img 0.05 0.1 0.2 for both
# selections, and the reference's top-8000 row), which did not fit the session's time.
if [ -n "${FULL:-}" ]; then
    GRID="nn:0.05 nn:0.1 nn:0.2 mutual:0.05 mutual:0.1 mutual:0.2"
else
    GRID="nn:0.05 nn:0.1 mutual:0.1"
fi
for cell in $GRID; do
    sel="${cell%%:*}" tau="${cell##*:}"
    run "$VFM-oracle-noisy-and-$sel-tau$tau" --wfm oracle --vfm "$VFM" --fusion noisy-and \
        --selection "$sel" --tau-img "$tau"
done
# The reference's selection (dual softmax, global top-8000) on the same frames.
[ -n "${FULL:-}" ] && run "$VFM-oracle-noisy-and-reference" --wfm oracle --vfm "$VFM" --fusion noisy-and --reference
"$BIN" table "$OUT"/fpfh-*.json "$OUT/$VFM"-*.json | tee "$OUT/table-$VFM.md"
