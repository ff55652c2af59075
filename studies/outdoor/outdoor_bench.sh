#!/usr/bin/env bash
# The outdoor LiDAR rows of BENCHMARKS.md ("Outdoor LiDAR") in one run: every outdoor data set
# with the published single-voxel preset (outdoor) and with the scale search (outdoor-search),
# then Open3D 0.20 FPFH + RANSAC on the same pairs (studies/outdoor/open3d_outdoor.sh, scratch venv).
# Each cgenreg run computes every stage (--no-cache) so its times are real.
#   CGENREG_BIN  the binary (default target/release/cgenreg, else target/debug/cgenreg)
#   OUT          output folder (default studies/outdoor/results/bench)
#   NO_OPEN3D=1  skip Open3D's row
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$root"
bin="${CGENREG_BIN:-}"
if [ -z "$bin" ]; then
  if [ -x target/release/cgenreg ]; then bin=target/release/cgenreg; else bin=target/debug/cgenreg; fi
fi
out="${OUT:-studies/outdoor/results/bench}"
mkdir -p "$out"
m=assets/manifests  # relative: run files name the manifest as the repository does
run() { # name, then bench arguments
  local name="$1"; shift
  echo "== $name: bench $*"
  "$bin" bench "$@" --no-cache --no-resume --json "$out/$name.json" | grep -E '^\| [a-z]' || true
}
run dev-pandaset-outdoor "$m/pandaset-dev.toml" --preset outdoor
run dev-pandaset-outdoor-search "$m/pandaset-dev.toml" --preset outdoor-search
run cgenreg-kitti07 "$m/kitti07.toml"
run cgenreg-kitti07-search "$m/kitti07.toml" --preset outdoor-search
run cgenreg-pandaset "$m/pandaset-lidar.toml" --preset outdoor
run cgenreg-pandaset-search "$m/pandaset-lidar.toml"
run cgenreg-lidar "$m/small-gicp-lidar.toml" --preset outdoor
run cgenreg-lidar-search "$m/small-gicp-lidar.toml" --preset outdoor-search
if [ "${NO_OPEN3D:-}" != 1 ]; then
  bash studies/outdoor/open3d_outdoor.sh --json "$out/open3d-outdoor.json" \
    "$m/kitti07.toml" "$m/pandaset-lidar.toml" "$m/small-gicp-lidar.toml"
fi
