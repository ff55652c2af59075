#!/usr/bin/env bash
# The Table-4 rows on the EVALUATED pairs (assets/manifests/redkitchen-rgbd.toml: 27 3DMatch +
# 10 3DLoMatch) for one VFM and one frame source, with the values frozen on the development
# set (docs/ablation.md, "Evaluation protocol"): FPFH alone (NN and mutual NN), image only,
# concatenation, Noisy-OR, Noisy-AND, and the reference's calibration and selection
# (--reference). Every option not on a line is the default. Nothing here is chosen from
# these results.
#
#   bash studies/ablation/ablation_vfm.sh VFM [WFM] [OUT_DIR]    # VFM xfeat|alike|disk, WFM oracle|builtin
#
# Env: CGENREG_BIN (default target/debug/cgenreg), CGENREG_CACHE (default
# ~/.cache/cgenreg-devset), CGENREG_DATA, SELECTION (the frozen selection of the fused rows;
# default: the pipeline's default).
set -euo pipefail
cd "$(dirname "$0")/../.."
VFM="${1:?VFM: xfeat|alike|disk}"
WFM="${2:-oracle}"
OUT="${3:-studies/ablation/results/vfm}"
BIN="${CGENREG_BIN:-target/debug/cgenreg}"
CACHE="${CGENREG_CACHE:-$HOME/.cache/cgenreg-devset}"
M=assets/manifests/redkitchen-rgbd.toml
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
mkdir -p "$OUT"
SEL=()
[ -n "${SELECTION:-}" ] && SEL=(--selection "$SELECTION")

run() { # name, then bench options
    local name="$1"; shift
    echo "== $name: cgenreg bench $M $* --cache-dir $CACHE --json $OUT/$name.json" >&2
    nice -n 10 "$BIN" bench "$M" "$@" --cache-dir "$CACHE" --json "$OUT/$name.json" > "$OUT/$name.txt"
}

# Most important rows first (a run cut short still has them); bench resumes a row's JSON.
run fpfh-nn --selection nn
for f in noisy-and image noisy-or concat; do
    run "$VFM-$WFM-$f" --wfm "$WFM" --vfm "$VFM" --fusion "$f" "${SEL[@]}"
done
run "$VFM-$WFM-reference" --wfm "$WFM" --vfm "$VFM" --fusion noisy-and --reference
run fpfh-mutual --selection mutual
"$BIN" table "$OUT"/fpfh-nn.json "$OUT"/fpfh-mutual.json \
    "$OUT/$VFM-$WFM"-{image,concat,noisy-or,noisy-and,reference}.json | tee "$OUT/table-$VFM-$WFM.md"
