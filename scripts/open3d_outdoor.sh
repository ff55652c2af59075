#!/usr/bin/env bash
# Open3D 0.20 FPFH + RANSAC on the outdoor benchmarks, beside `cgenreg bench` (docs/outdoor.md).
# Installs open3d into a scratch virtual environment (never the system's pip), then runs
# scripts/open3d_outdoor.py on the given manifests (default: KITTI 07 and PandaSet).
#
#   CGENREG_DATA=/path/to/data scripts/open3d_outdoor.sh [--json OUT.json] [MANIFEST.toml ...]
#
# Environment: O3D_VENV (default: target/open3d-venv), O3D_VERSION (default 0.20.0),
# O3D_PACKAGE (default open3d-cpu; `open3d` for the GPU wheel).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
venv="${O3D_VENV:-$repo/target/open3d-venv}"
version="${O3D_VERSION:-0.20.0}"
package="${O3D_PACKAGE:-open3d-cpu}"
if [ ! -x "$venv/bin/python" ] ||
    ! "$venv/bin/python" -c "import open3d, sys; sys.exit(open3d.__version__ != sys.argv[1])" "$version" 2>/dev/null; then
    bash "$here/venv_install.sh" "$venv" "$package==$version"
fi
args=("$@")
has_manifest=0
for x in "${args[@]+"${args[@]}"}"; do
    case "$x" in *.toml) has_manifest=1 ;; esac
done
if [ "$has_manifest" = 0 ]; then
    args+=("$repo/assets/manifests/kitti07.toml" "$repo/assets/manifests/pandaset-lidar.toml")
fi
exec "$venv/bin/python" "$here/open3d_outdoor.py" "${args[@]}"
