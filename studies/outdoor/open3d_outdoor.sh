#!/usr/bin/env bash
# Open3D 0.20 FPFH + RANSAC on the outdoor benchmarks, beside `cgenreg bench` (docs/outdoor.md):
# scripts/peers.sh --method open3d with the outdoor protocol's voxel (0.3 m) and criteria
# (5° / 2 m and 5° / 0.6 m) unless given, on the given manifests (default: KITTI 07 and PandaSet).
#
#   CGENREG_DATA=/path/to/data studies/outdoor/open3d_outdoor.sh [--voxel V] [--seed S]
#       [--success RRE_DEG:RTE_M ...] [--json OUT.json] [MANIFEST.toml ...]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$(dirname "$here")")"
args=("$@")
has_manifest=0 has_voxel=0 has_success=0
for x in "${args[@]+"${args[@]}"}"; do
    case "$x" in
    *.toml) has_manifest=1 ;;
    --voxel | --voxel=*) has_voxel=1 ;;
    --success | --success=*) has_success=1 ;;
    esac
done
[ "$has_voxel" = 1 ] || args=(--voxel 0.3 "${args[@]+"${args[@]}"}")
[ "$has_success" = 1 ] || args=(--success 5:2 --success 5:0.6 "${args[@]+"${args[@]}"}")
if [ "$has_manifest" = 0 ]; then
    args+=("$repo/assets/manifests/kitti07.toml" "$repo/assets/manifests/pandaset-lidar.toml")
fi
export PEERS_COMMAND="${PEERS_COMMAND:-studies/outdoor/open3d_outdoor.sh}"
exec bash "$repo/scripts/peers.sh" --method open3d "${args[@]}"
