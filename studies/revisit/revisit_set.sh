#!/usr/bin/env bash
# The revisit set (docs/ablation.md, "Revisits"): the candidate fragments and pairs, their GT
# overlap, the pairs the frozen rule picks (assets/manifests/redkitchen-revisit.toml), and every
# fragment of it written as PLY with a clouds-only manifest (target/revisit/clouds.toml) for the
# clouds-only rows and Open3D.
#
#   bash studies/revisit/revisit_set.sh [CACHE_DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${1:-${CGENREG_CACHE:-$HOME/.cache/cgenreg}}"
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
OUT=target/revisit
M=assets/manifests/redkitchen-revisit.toml
EX="${CGENREG_EXAMPLE_DIR:-target/debug/examples}"
mkdir -p "$OUT"
C="$OUT/candidates.toml"
. studies/dev-sweep/redkitchen_fragments.sh
{
    fragments_header redkitchen-revisit-candidates
    starts=()
    for k in $(seq 0 8); do
        for o in 10 20 30 40; do
            starts+=($((50 * k + o)))
        done
    done
    for f in "${starts[@]}"; do
        fragment_entry "$f"
    done
    for a in "${starts[@]}"; do
        for b in "${starts[@]}"; do
            if [ $((b - a)) -ge 200 ]; then
                gt_pose_pair "$a" "$b"
            fi
        done
    done
} > "$C"
if [ ! -e "$M" ]; then
    nice -n 10 "$EX/pair_overlap" "$C" "$CACHE" > "$OUT/overlap.tsv"
    python3 studies/revisit/revisit_select.py "$C" "$OUT/overlap.tsv" "$M"
fi
nice -n 10 "$EX/export_fragments" "$M" "$OUT" "$CACHE"
