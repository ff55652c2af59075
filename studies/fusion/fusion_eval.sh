#!/usr/bin/env bash
# The evaluated rows of the fusion study (docs/ablation.md, "A fusion that never loses to its
# best branch"): for every evaluated set, with ALIKE-t and oracle RGB where the data has colour
# (built-in frames otherwise), five runs: the default fusion (visibility), the union, the
# paper's Noisy-AND, the image branch alone and the geometric branch alone (no image branch:
# FPFH, NN). The image branch's stages are cached by the first run, so the others cost only the
# in-memory tail. MODES (default "visibility union noisy-and image geometry") picks the runs.
# Tables: python3 studies/fusion/fusion_tables.py OUT
#
#   bash studies/fusion/fusion_eval.sh SET [OUT_DIR]   # SET: staged-clouds rgbd-3dlomatch lidar staged staged-builtin rgbd-3dmatch kitti07 revisit revisit-clouds
#
# Env: CGENREG_BIN (default target/debug/cgenreg), CGENREG_CACHE (stage cache folder),
# CGENREG_DATA. A run cut short resumes (bench --json resumes).
set -euo pipefail
cd "$(dirname "$0")/../.."
SET="${1:?SET}"
OUT="${2:-studies/fusion/results/eval}"
BIN="${CGENREG_BIN:-target/debug/cgenreg}"
CACHE="${CGENREG_CACHE:-$HOME/.cache/cgenreg}"
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
mkdir -p "$OUT"
case "$SET" in
    staged-clouds) M=assets/manifests/redkitchen-staged-clouds.toml; O=(--wfm builtin) ;;
    rgbd-3dlomatch) M=assets/manifests/redkitchen-rgbd.toml; O=(--split 3DLoMatch --wfm oracle) ;;
    rgbd-3dmatch) M=assets/manifests/redkitchen-rgbd.toml; O=(--split 3DMatch --wfm oracle) ;;
    staged) M=assets/manifests/redkitchen-staged.toml; O=(--wfm oracle) ;;
    # the same pairs with built-in frames shaded from the sensor's depth: the image branch for
    # the pair without colour frames (21-34), which the oracle cannot run
    staged-builtin) M=assets/manifests/redkitchen-staged.toml; O=(--wfm builtin) ;;
    lidar) M=assets/manifests/small-gicp-lidar.toml; O=(--wfm builtin) ;;
    revisit) M=assets/manifests/redkitchen-revisit.toml; O=(--wfm oracle) ;;
    # the revisit pairs as plain PLY files (studies/revisit/revisit_set.sh writes them; derived from the data)
    revisit-clouds) M=target/revisit/clouds.toml; O=(--wfm builtin) ;;
    # xyz-only LiDAR: `auto` would pick the pinhole trajectory (it looks for intensity)
    kitti07) M=assets/manifests/kitti07.toml; O=(--virtual-camera ftheta --wfm builtin) ;;
    *) echo "unknown set $SET" >&2; exit 2 ;;
esac
run() { # mode name, then bench options
    local name="$SET-$1"; shift
    echo "== $name: cgenreg bench $M $* --json $OUT/$name.json" >&2
    nice -n 5 "$BIN" bench "$M" "$@" --cache-dir "$CACHE" --json "$OUT/$name.json" \
        > "$OUT/$name.txt" || echo "$name: exit $?" >&2
    # the log names the cache folder; results are committed without machine paths
    sed -i "s|$CACHE|CACHE|g" "$OUT/$name.txt"
}
MODES="${MODES:-visibility union noisy-and image geometry}"
for m in $MODES; do
    case "$m" in
        visibility) run visibility "${O[@]}" --vfm alike ;;
        union | noisy-and | image) run "$m" "${O[@]}" --vfm alike --fusion "$m" ;;
        # geometry alone: the same pairs without the image branch (--wfm dropped)
        geometry) run geometry "${O[@]:0:${#O[@]}-2}" ;;
        *) echo "unknown mode $m" >&2; exit 2 ;;
    esac
done
