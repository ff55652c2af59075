#!/usr/bin/env bash
# Fresh development pairs for a round of the fusion study (docs/ablation.md): write
# assets/manifests/redkitchen-devN.toml (3DLoMatch-like pairs of fragments starting at 50k+OFFSET,
# unless it exists), then run the study example on DN (oracle RGB + ALIKE-t) and DNc (the same pairs
# clouds only, built-in frames + ALIKE-t). Each pair's line is appended to
# studies/fusion/results/dev/vis-DN.jsonl / vis-DNc.jsonl as it finishes; pairs already there are skipped.
#
#   bash studies/fusion/fusion_dev_round.sh N "OFFSETS" CACHE_DIR
set -euo pipefail
cd "$(dirname "$0")/../.."
N="${1:?usage: fusion_dev_round.sh N \"OFFSETS\" CACHE_DIR}"
OFFSETS="${2:?usage: fusion_dev_round.sh N \"OFFSETS\" CACHE_DIR}"
CACHE="${3:?usage: fusion_dev_round.sh N \"OFFSETS\" CACHE_DIR}"
O=studies/fusion/results/dev
BIN="${CGENREG_EXAMPLE_BIN:-target/debug/examples/fusion_study}"
D="assets/manifests/redkitchen-dev$N.toml"
if [ ! -e "$D" ]; then
    OFFSETS="$OFFSETS" DEV_NAME="redkitchen-dev$N" DEV_MANIFEST="$D" \
        LOMATCH_ONLY=1 bash studies/dev-sweep/devset_candidates.sh "target/devset$N" "$CACHE"
fi
nice -n 5 "$BIN" "$D" --wfm oracle --cache-dir "$CACHE" --out "$O/vis-D$N.jsonl"
nice -n 5 "$BIN" "$D" --wfm builtin --cache-dir "$CACHE" --out "$O/vis-D${N}c.jsonl" --clouds-only
