#!/usr/bin/env bash
# SpinNet alone vs FPFH alone (geometry only, SC2-PCR), each run with peak memory from
# /usr/bin/time. First the keypoint count on the development pair (redkitchen-dev's first pair,
# never evaluated): 256 or 512 keypoints per scan, the smaller one if it registers the pair,
# else 512 (the rule is fixed before any evaluated row is run). Then, at that count, the first
# two staged redkitchen pairs (spinnet-3dmatch) and the three nearest KITTI 07 pairs
# (spinnet-kitti), with FPFH beside them in the same run.
#   CGENREG_BIN   the binary (default target/release/cgenreg, else target/debug/cgenreg)
#   OUT           output folder (default target/spinnet-bench)
# Needs the exports of scripts/spinnet_export.sh. Summary: OUT/summary.json (scripts/spinnet_summary.py).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="${CGENREG_BIN:-}"
if [ -z "$bin" ]; then
  if [ -x "$root/target/release/cgenreg" ]; then bin="$root/target/release/cgenreg"; else bin="$root/target/debug/cgenreg"; fi
fi
out="${OUT:-$root/target/spinnet-bench}"
mkdir -p "$out"
cache="$out/cache"
m="$root/assets/manifests"

run() { # name, then bench arguments
  local name="$1"; shift
  echo "== $name: $*"
  /usr/bin/time -f '%e s wall, %M kB peak RSS' -o "$out/$name.time" \
    timeout 3600 "$bin" bench "$@" --json "$out/$name.json" --no-resume --cache-dir "$cache" \
    > "$out/$name.log" 2>&1 || echo "$name failed: see $out/$name.log"
  cat "$out/$name.time"
}

success() { # run file -> number of successes
  python3 -c 'import json,sys; print(sum(1 for p in json.load(open(sys.argv[1]))["pairs"] if p.get("success")))' "$1"
}

# 1. development pair: the keypoint count
run dev-fpfh "$m/redkitchen-dev.toml" --limit 1
for n in 256 512; do
  run "dev-spinnet-$n" "$m/redkitchen-dev.toml" --limit 1 --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
done
if [ "$(success "$out/dev-spinnet-256.json")" = 1 ]; then n=256; else n=512; fi
echo "keypoints chosen on the development pair: $n" | tee "$out/chosen.txt"

# 2. evaluated rows at that count
run staged-fpfh "$m/redkitchen-staged.toml" --limit 2
run "staged-spinnet-$n" "$m/redkitchen-staged.toml" --limit 2 --geo-features spinnet-3dmatch --spinnet-keypoints "$n"
run kitti-fpfh "$m/kitti07.toml" --limit 3
run "kitti-spinnet-$n" "$m/kitti07.toml" --limit 3 --geo-features spinnet-kitti --spinnet-keypoints "$n"
echo done
