#!/usr/bin/env bash
# The sixth round of the fusion study (docs/ablation.md): write the fresh development manifest (D6),
# run the study example on D6 and D6c (each pair's line appended as it finishes; pairs already in a
# file are skipped), then the tables over every round's lines.
#
#   bash studies/fusion/fusion_share_study.sh CACHE_DIR
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${1:?usage: fusion_share_study.sh CACHE_DIR}"
O=studies/fusion/results/dev
bash studies/fusion/fusion_dev_round.sh 6 "15 34 47" "$CACHE"
args=()
for s in D6 D6c D1 D2 D3 D3c D4 D4c D5 D5c; do args+=("$s=$O/vis-$s.jsonl"); done
python3 studies/fusion/fusion_study6.py --virtual D2,D3c,D4c,D5c,D6c --fresh D6,D6c "${args[@]}" > "$O/study6.md"
cat "$O/study6.md"
