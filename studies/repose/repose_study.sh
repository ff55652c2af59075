#!/usr/bin/env bash
# Is a one-pair margin on 3DLoMatch the method or the coordinate frame? Re-run rows of the
# evaluated ablation (assets/manifests/redkitchen-rgbd.toml, 3DLoMatch split) with every
# source turned by a seeded random rotation about its origin (`bench --repose-seed N`: uniform
# on SO(3); frames and GT turned with it; the origin is the fragment's viewpoint and stays).
# The problems are the same; only voxel grids, keypoints and tie-breaks change. Frozen values,
# nothing tuned.
#
#   bash studies/repose/repose_study.sh [OUT_DIR] [SEEDS]      # default studies/repose/results, "1 2 3 4 5"
#
# Env: CGENREG_BIN (default target/release/cgenreg), CGENREG_CACHE, CGENREG_DATA.
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-studies/repose/results}"
SEEDS="${2:-1 2 3 4 5}"
BIN="${CGENREG_BIN:-target/release/cgenreg}"
CACHE="${CGENREG_CACHE:-$HOME/.cache/cgenreg-repose}"
M=assets/manifests/redkitchen-rgbd.toml
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
mkdir -p "$OUT"
run() { # name, seed, then bench options
    local name="$1" seed="$2"; shift 2
    echo "== $name seed $seed: cgenreg bench $M --split 3DLoMatch --repose-seed $seed $*" >&2
    nice -n 5 "$BIN" bench "$M" --split 3DLoMatch --repose-seed "$seed" "$@" --cache-dir "$CACHE" \
        --json "$OUT/$name-seed$seed.json" > "$OUT/$name-seed$seed.txt"
}
# Seed by seed, so a run cut short still compares the rows on the same frames.
for s in $SEEDS; do
    run fpfh-nn "$s" --selection nn
    run alike-oracle-noisy-and "$s" --wfm oracle --vfm alike --fusion noisy-and
    run alike-oracle-image "$s" --wfm oracle --vfm alike --fusion image
done
