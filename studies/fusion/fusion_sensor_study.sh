#!/usr/bin/env bash
# The fifth round of the fusion study (docs/ablation.md): write the fresh development manifest (D5),
# run the study example on D5 and D5c (each pair's line appended as it finishes; pairs already in a
# file are skipped), then the tables over every round's lines.
#
#   bash studies/fusion/fusion_sensor_study.sh CACHE_DIR
set -euo pipefail
cd "$(dirname "$0")/../.."
CACHE="${1:?usage: fusion_sensor_study.sh CACHE_DIR}"
O=studies/fusion/results/dev
bash studies/fusion/fusion_dev_round.sh 5 "18 43" "$CACHE"
python3 studies/fusion/fusion_study5.py --virtual D2,D3c,D4c,D5c --fresh D5,D5c \
    D5="$O/vis-D5.jsonl" D5c="$O/vis-D5c.jsonl" D1="$O/vis-D1.jsonl" D2="$O/vis-D2.jsonl" \
    D3="$O/vis-D3.jsonl" D3c="$O/vis-D3c.jsonl" D4="$O/vis-D4.jsonl" D4c="$O/vis-D4c.jsonl" \
    > "$O/study5.md"
cat "$O/study5.md"
