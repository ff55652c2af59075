#!/usr/bin/env bash
# Candidate development fragments for redkitchen and the GT overlap of every pair among them:
# fragments of 50 frames starting at frame 50k+OFFSET (k = 0..8; OFFSET 25 by default: frames
# 25-74, 75-124, ..., 425-474, i.e. offset by half a fragment from the evaluated fragments of
# assets/manifests/redkitchen-rgbd.toml, frames 50k..50k+49). GT from the frame poses
# (gt_poses = true). Writes the candidate manifest to $OUT/candidates.toml and the overlap
# table to $OUT/overlap.tsv; the development manifest keeps the pairs the rule in
# docs/ablation.md picks.
#
#   bash studies/dev-sweep/devset_candidates.sh [OUT_DIR] [CACHE_DIR]
#
# Environment:
#   OFFSETS       fragment start offsets, space-separated (default "25"); pairs are only formed
#                 between fragments of the same offset
#   DEV_NAME      the dataset name (default redkitchen-dev)
#   DEV_MANIFEST  the manifest written (default assets/manifests/redkitchen-dev.toml)
#   LOMATCH_ONLY  1: keep only 3DLoMatch-like pairs (10-30 % overlap); default: every pair >= 10 %
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-target/devset}"
CACHE="${2:-${CGENREG_CACHE:-$HOME/.cache/cgenreg}}"
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
OFFSETS="${OFFSETS:-25}"
NAME="${DEV_NAME:-redkitchen-dev}"
LOMATCH_ONLY="${LOMATCH_ONLY:-0}"
mkdir -p "$OUT"
M="$OUT/candidates.toml"
. studies/dev-sweep/redkitchen_fragments.sh
{
    fragments_header "$NAME"
    for o in $OFFSETS; do
        for k in $(seq 0 8); do
            fragment_entry $((50 * k + o))
        done
    done
    for o in $OFFSETS; do
        for i in $(seq 0 8); do
            for j in $(seq $((i + 1)) 8); do
                gt_pose_pair $((50 * i + o)) $((50 * j + o))
            done
        done
    done
} > "$M"
nice -n 10 "${CGENREG_EXAMPLE_BIN:-target/debug/examples/pair_overlap}" "$M" "$CACHE" | tee "$OUT/overlap.tsv"

# The rule: keep every candidate pair whose overlap (max of the two directions) is at least
# 10 % (with LOMATCH_ONLY=1: at most 30 % too); split "3DMatch-like" above 30 %,
# "3DLoMatch-like" from 10 to 30 % (3DLoMatch's range).
DEV="${DEV_MANIFEST:-assets/manifests/redkitchen-dev.toml}"
{
    echo '# DEVELOPMENT SET (never evaluated; docs/ablation.md "Evaluation protocol"). Written by'
    echo "# studies/dev-sweep/devset_candidates.sh (OFFSETS=\"$OFFSETS\" LOMATCH_ONLY=$LOMATCH_ONLY). 7-Scenes"
    echo "# redkitchen fragments of 50 raw frames starting at frame 50k+offset (k = 0..8), in the camera"
    echo '# frame of their first frame; the evaluated fragments of redkitchen-rgbd.toml are frames'
    echo '# 50k..50k+49: same room, same raw frames, different fragment boundaries and different pairs.'
    echo '# GT: gt_poses = true, target_from_source = inv(P_target_first) * P_source_first.'
    echo '# Pairs: fragments of the same offset with GT overlap >= 10 % (metrics::overlap: 2.5 cm'
    echo '# voxel, 3.75 cm radius, max of both directions); > 30 %: 3DMatch-like, 10-30 %: 3DLoMatch-like.'
    sed -n '1,/^\[\[pairs\]\]/p' "$M" | sed '$d'
    awk -F'\t' -v lo="$LOMATCH_ONLY" '!/^#/ && $5 >= 10 && (lo != 1 || $5 <= 30) {
        split($1, a, "/"); split(a[2], b, "-");
        printf "\n[[pairs]]\n# overlap %s %% (source %s %%, target %s %%)\ntarget = \"%s\"\nsource = \"%s\"\nsplit = \"%s\"\ngt_poses = true\n",
            $5, $3, $4, b[1], b[2], ($5 > 30 ? "3DMatch-like" : "3DLoMatch-like")
    }' "$OUT/overlap.tsv"
} > "$DEV"
echo "wrote $DEV: $(grep -c '^\[\[pairs' "$DEV") pairs" >&2
