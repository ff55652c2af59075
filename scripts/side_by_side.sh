#!/usr/bin/env bash
# cgenreg and the peers a user would pick instead (KISS-Matcher and Open3D FPFH + RANSAC, through
# scripts/peers.sh) on the same pairs, one after the other in one run: the staged redkitchen pairs
# as cloud files (indoor, voxel 0.05 m), KITTI 07 (outdoor preset, voxel 0.3 m) and PandaSet
# (cgenreg's outdoor-search; the peers at the outdoor voxel 0.3 m, their default outdoors).
# cgenreg: geometry alone (FPFH, nearest-neighbour selection, SC2-PCR), release build, every stage
# computed (--no-cache): its per-pair time is the whole pair, loading included. The peers' JSON
# holds their estimate time (clouds in memory) and whole-pair time (loading included).
#
#   CGENREG_DATA=/path/to/data bash scripts/side_by_side.sh [OUT_DIR]
#   python3 scripts/lib/side_by_side.py   # the table in BENCHMARKS.md from OUT_DIR's JSONs
#
# Environment: CGENREG_BIN (default target/release/cgenreg), PEERS_SH (default scripts/peers.sh),
# PEERS_VENV (peers.sh's scratch venv), SETS (default "staged kitti07 pandaset").
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-$root/docs/results/peers}"
bin="${CGENREG_BIN:-$root/target/release/cgenreg}"
peers="${PEERS_SH:-$root/scripts/peers.sh}"
mkdir -p "$out"
manifest() {
    case "$1" in
    staged) echo "$root/assets/manifests/redkitchen-staged-clouds.toml" ;;
    kitti07) echo "$root/assets/manifests/kitti07.toml" ;;
    pandaset) echo "$root/assets/manifests/pandaset-lidar.toml" ;;
    *) echo "side_by_side: unknown set '$1' (staged, kitti07, pandaset)" >&2; exit 2 ;;
    esac
}
{
    echo "date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"
    echo "machine: $(uname -srm), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //')"
    echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
    echo "cgenreg: ${bin#"$root"/} (release build of $(git -C "$root" rev-parse --short HEAD))"
} > "$out/run.txt"
# paths relative to the repository, as the JSONs record them
cd "$root"
for set in ${SETS:-staged kitti07 pandaset}; do
    m="$(manifest "$set")"
    m="${m#"$root"/}"
    o="${out#"$root"/}"
    "$bin" bench "$m" --no-cache --no-resume --json "$o/cgenreg-$set.json" > "$o/cgenreg-$set.txt"
    PEERS_COMMAND=scripts/peers.sh bash "$peers" --method all --json "$o/peers-$set.json" "$m" > "$o/peers-$set.txt"
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out/run.txt"
