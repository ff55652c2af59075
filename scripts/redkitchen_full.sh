#!/usr/bin/env bash
# The whole redkitchen part of 3DMatch (506 pairs) and 3DLoMatch (525) in one run, by the protocol of
# docs/standard-benchmarks.md: the fragments and the official gt.log / gt.info laid out as Predator does
# (symbolic links under the build folder), a manifest by `cgenreg dataset 3dmatch`, then `cgenreg bench`
# (geometry alone, the indoor preset, no cache) and the peers (scripts/peers.sh: KISS-Matcher and Open3D
# FPFH + RANSAC at voxel 0.05 m) on the same pairs.
#   CGENREG_DATA  the data folder (3dmatch-redkitchen-full/, 3dmatch-redkitchen/benchmark/)
#   CGENREG_BIN   the binary (default target/release/cgenreg)
#   OUT           output folder (default docs/results/redkitchen-full)
#   STEPS         which steps, default "manifest cgenreg peers score"; `score` scores the peers' poses with
#                 `cgenreg score` (the same formulas as cgenreg's own rows, the official recall included)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
data="${CGENREG_DATA:?set CGENREG_DATA to the data folder}"
bin="${CGENREG_BIN:-target/release/cgenreg}"
out="${OUT:-docs/results/redkitchen-full}"
steps="${STEPS:-manifest cgenreg peers score}"
work=target/redkitchen-full
manifest="$work/redkitchen-full.toml"  # relative: run files name it as given
mkdir -p "$out" "$work"
scene=7-scenes-redkitchen
for step in $steps; do
  case "$step" in
  manifest)
    rm -rf "$work/layout"
    mkdir -p "$work/layout"
    ln -s "$data/3dmatch-redkitchen-full" "$work/layout/$scene"
    for b in 3DMatch 3DLoMatch; do
      mkdir -p "$work/layout/benchmarks/$b/$scene"
      for f in gt.log gt.info; do
        ln -s "$data/3dmatch-redkitchen/benchmark/$b/$f" "$work/layout/benchmarks/$b/$scene/$f"
      done
    done
    "$bin" dataset 3dmatch "$work/layout" --out "$manifest" --force
    ;;
  cgenreg)
    "$bin" bench "$manifest" --no-cache --no-resume --json "$out/cgenreg-geometry.json" \
      >"$work/cgenreg-geometry.txt"
    sed -n '/^Per benchmark/,/^$/p' "$work/cgenreg-geometry.txt"
    ;;
  peers)
    PEERS_COMMAND=scripts/peers.sh bash scripts/peers.sh --json "$out/peers.json" "$manifest" \
      >"$work/peers.txt"
    grep -E "registered at|mean s/pair|^KISS|^Open3D" "$work/peers.txt"
    ;;
  score)
    names=(kiss-matcher open3d) # the runs of peers.json, in order
    for k in 0 1; do
      name="${names[$k]}"
      "$bin" score "$manifest" "$out/peers.json" --run "$k" --force --json "$out/peers-$name-scored.json" \
        >"$work/peers-$name-scored.txt"
      sed -n '/^Per benchmark/,/^$/p' "$work/peers-$name-scored.txt"
    done
    ;;
  *) echo "redkitchen_full.sh: unknown step $step (manifest, cgenreg, peers, score)" >&2; exit 2 ;;
  esac
done
