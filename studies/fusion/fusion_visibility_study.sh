#!/usr/bin/env bash
# The fourth round of the fusion study (docs/ablation.md): write the fresh development manifest
# (D4), then run the study example on D4, D4c, D3, D3c, D1, D2 in that order (each pair's line is
# appended as it finishes; pairs already in a file are skipped), then the tables.
#
#   bash studies/fusion/fusion_visibility_study.sh CACHE_DIR
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${1:?usage: fusion_visibility_study.sh CACHE_DIR}"
O=studies/fusion/results/dev
BIN="${CGENREG_EXAMPLE_BIN:-target/debug/examples/fusion_study}"
if [ ! -e assets/manifests/redkitchen-dev4.toml ]; then
    OFFSETS="6 31" DEV_NAME=redkitchen-dev4 DEV_MANIFEST=assets/manifests/redkitchen-dev4.toml \
        LOMATCH_ONLY=1 bash studies/dev-sweep/devset_candidates.sh target/devset4 "$CACHE"
fi
run() { # manifest, wfm, out, extra...
    local m="$1" w="$2" out="$3"
    shift 3
    nice -n 5 "$BIN" "$m" --wfm "$w" --cache-dir "$CACHE" --out "$out" "$@"
}
D4=assets/manifests/redkitchen-dev4.toml D3=assets/manifests/redkitchen-dev3.toml
D1=assets/manifests/redkitchen-dev.toml
run "$D4" oracle "$O/vis-D4.jsonl"
run "$D4" builtin "$O/vis-D4c.jsonl" --clouds-only
run "$D3" oracle "$O/vis-D3.jsonl"
run "$D3" builtin "$O/vis-D3c.jsonl" --clouds-only
for s in 3DLoMatch-like 3DMatch-like; do
    run "$D1" oracle "$O/vis-D1.jsonl" --split "$s"
    run "$D1" builtin "$O/vis-D2.jsonl" --clouds-only --split "$s"
done
