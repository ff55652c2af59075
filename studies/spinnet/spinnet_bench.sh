#!/usr/bin/env bash
# SpinNet alone vs FPFH alone (geometry only, SC2-PCR), each run with wall time, CPU time and
# peak memory from /usr/bin/time. First the keypoint count on the development pair
# (redkitchen-dev's first pair, never evaluated): 128 or 256 keypoints per scan, the smaller if
# it registers the pair, else 256 (the rule is fixed before any evaluated row is run). Then, at
# that count, every staged redkitchen pair (spinnet-3dmatch) and every KITTI 07 pair
# (spinnet-kitti), with FPFH beside them in the same run. Each scan is described once (the
# geo-spinnet stage's cache), so the time of a set is about scans x keypoints. A run whose
# .json and .time are already in OUT is kept (delete them to rerun).
#   CGENREG_BIN   the binary (default target/release/cgenreg, else target/debug/cgenreg)
#   OUT           output folder (default target/spinnet-bench)
#   PROBE=1       also KITTI 07 at 512 keypoints (a sensitivity figure, see below)
#   FUSED=1       also the rows fused with the image branch, and redkitchen-rgbd (step 4)
#   DEV_ALL=1     also every development pair at 128 and 256 keypoints (step 5)
#   REPOSE="1 2"  also redkitchen-rgbd 3DLoMatch re-posed by these seeds, each branch (step 6)
#   BUILTIN=1     also built-in frames fused with each branch on the indoor sets (step 7)
#   KEYPOINTS=N   the evaluated rows at N keypoints instead of step 1's choice
# Needs the exports of models/spinnet_export.sh. Summary: studies/spinnet/spinnet_summary.py OUT.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
bin="${CGENREG_BIN:-}"
if [ -z "$bin" ]; then
  if [ -x "$root/target/release/cgenreg" ]; then bin="$root/target/release/cgenreg"; else bin="$root/target/debug/cgenreg"; fi
fi
out="${OUT:-$root/target/spinnet-bench}"
mkdir -p "$out"
cache="$out/cache"
cd "$root"
m="assets/manifests"  # relative: run files name the manifest as the repository does

run() { # name, then bench arguments
  local name="$1"; shift
  if [ -s "$out/$name.json" ] && [ -s "$out/$name.time" ]; then echo "== $name: kept"; return; fi
  echo "== $name: $*"
  /usr/bin/time -f '%e s wall, %U s user, %S s system, %M kB peak RSS' -o "$out/$name.time" \
    timeout 3600 "$bin" bench "$@" --json "$out/$name.json" --no-resume --cache-dir "$cache" \
    > "$out/$name.log" 2>&1 || echo "$name failed: see $out/$name.log"
  cat "$out/$name.time"
}

success() { # run file -> number of successes
  python3 -c 'import json,sys; print(sum(1 for p in json.load(open(sys.argv[1]))["pairs"] if p.get("success")))' "$1"
}

# 1. development pair: the keypoint count
run dev-fpfh "$m/redkitchen-dev.toml" --limit 1
for n in 128 256; do
  run "dev-spinnet-$n" "$m/redkitchen-dev.toml" --limit 1 --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
done
if [ "$(success "$out/dev-spinnet-128.json")" = 1 ]; then n=128; else n=256; fi
echo "keypoints chosen on the development pair: $n" | tee "$out/chosen.txt"
# KEYPOINTS=N: the evaluated rows below at N keypoints instead (the count chosen on every
# development pair, step 5: 256 registers 23 of 30 where 128 registers 16).
if [ -n "${KEYPOINTS:-}" ]; then
  n="$KEYPOINTS"
  echo "keypoints from KEYPOINTS (chosen on every development pair): $n" | tee -a "$out/chosen.txt"
fi

# 2. evaluated rows at that count
run kitti-fpfh "$m/kitti07.toml"
run "kitti-spinnet-$n" "$m/kitti07.toml" --geo-features spinnet-kitti --spinnet-keypoints "$n"
run staged-fpfh "$m/redkitchen-staged.toml"
run "staged-spinnet-$n" "$m/redkitchen-staged.toml" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
# 3. PROBE=1: how the outdoor result moves with the keypoint count (KITTI has no development set
# here, so this is a sensitivity figure on evaluated pairs, not a choice: the default stays)
if [ "${PROBE:-}" = 1 ]; then
  run kitti-spinnet-512-probe "$m/kitti07.toml" --geo-features spinnet-kitti --spinnet-keypoints 512
fi
# 4. FUSED=1: the image branch with each geometric branch, the default fusion (visibility), FPFH
# beside SpinNet in the same run: oracle RGB + ALIKE-t on the staged and redkitchen-rgbd pairs
# (colour frames), built-in f-theta frames + ALIKE-t on KITTI 07 (xyz only); and the
# redkitchen-rgbd pairs with each branch alone.
if [ "${FUSED:-}" = 1 ]; then
  img=(--wfm oracle --vfm alike)
  run staged-fpfh-oracle "$m/redkitchen-staged.toml" "${img[@]}"
  run "staged-spinnet-$n-oracle" "$m/redkitchen-staged.toml" "${img[@]}" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
  run rgbd-fpfh "$m/redkitchen-rgbd.toml"
  run "rgbd-spinnet-$n" "$m/redkitchen-rgbd.toml" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
  run rgbd-fpfh-oracle "$m/redkitchen-rgbd.toml" "${img[@]}"
  run "rgbd-spinnet-$n-oracle" "$m/redkitchen-rgbd.toml" "${img[@]}" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
  lidar=(--wfm builtin --vfm alike --virtual-camera ftheta)
  run kitti-fpfh-builtin "$m/kitti07.toml" "${lidar[@]}"
  run "kitti-spinnet-$n-builtin" "$m/kitti07.toml" "${lidar[@]}" --geo-features spinnet-kitti --spinnet-keypoints "$n"
fi
# 5. DEV_ALL=1: every development pair (redkitchen-dev, never evaluated) at 128 and 256
# keypoints, FPFH beside: a check of the count step 1 chose on one pair.
if [ "${DEV_ALL:-}" = 1 ]; then
  run dev-all-fpfh "$m/redkitchen-dev.toml"
  for k in 128 256; do
    run "dev-all-spinnet-$k" "$m/redkitchen-dev.toml" --geo-features spinnet-3dmatch --spinnet-keypoints "$k"
  done
fi
# 6. REPOSE="1 2 ...": redkitchen-rgbd 3DLoMatch with every source turned by a seeded random
# rotation (`--repose-seed`, as studies/repose/repose_study.sh), each branch alone, seed by seed.
for s in ${REPOSE:-}; do
  rp=("$m/redkitchen-rgbd.toml" --split 3DLoMatch --repose-seed "$s")
  run "repose-fpfh-seed$s" "${rp[@]}"
  run "repose-spinnet-$n-seed$s" "${rp[@]}" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
done
# 7. BUILTIN=1: the built-in frames (the generator stand-in) + ALIKE-t fused with each geometric
# branch on the indoor sets (the default fusion), FPFH beside SpinNet in the same run.
if [ "${BUILTIN:-}" = 1 ]; then
  b=(--wfm builtin --vfm alike)
  run staged-fpfh-builtin "$m/redkitchen-staged.toml" "${b[@]}"
  run "staged-spinnet-$n-builtin" "$m/redkitchen-staged.toml" "${b[@]}" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
  run rgbd-fpfh-builtin "$m/redkitchen-rgbd.toml" "${b[@]}"
  run "rgbd-spinnet-$n-builtin" "$m/redkitchen-rgbd.toml" "${b[@]}" --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
fi
echo done
