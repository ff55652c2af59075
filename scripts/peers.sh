#!/usr/bin/env bash
# The peers beside `cgenreg bench`: KISS-Matcher (PyPI kiss-matcher) and Open3D 0.20 FPFH + RANSAC
# (PyPI open3d-cpu) on the pairs of cgenreg manifests whose fragments are cloud files. Installs both
# into a scratch virtual environment (never the system's pip), then runs scripts/lib/peers.py
# (its docstring states the protocol, the defaults and the JSON fields).
#
#   CGENREG_DATA=/path/to/data scripts/peers.sh [--method kiss|open3d|all] [--voxel V]
#       [--seed S] [--success RRE_DEG:RTE_M ...] [--pairs SUBSTRING ...] [--json OUT.json]
#       MANIFEST.toml [...]
#
# Voxel default: 0.05 m indoors, 0.3 m outdoors (the manifest's preset). Environment: PEERS_VENV
# (default: target/peers-venv), O3D_VERSION (0.20.0), O3D_PACKAGE (open3d-cpu; `open3d` for the GPU
# wheel), KISS_VERSION (1.0.2).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
venv="${PEERS_VENV:-$repo/target/peers-venv}"
o3d_version="${O3D_VERSION:-0.20.0}"
o3d_package="${O3D_PACKAGE:-open3d-cpu}"
kiss_version="${KISS_VERSION:-1.0.2}"
if [ ! -x "$venv/bin/python" ] ||
    ! "$venv/bin/python" - "$o3d_version" "$kiss_version" 2>/dev/null <<'PY'
import sys
from importlib.metadata import version
import open3d
sys.exit(open3d.__version__ != sys.argv[1] or version("kiss-matcher") != sys.argv[2])
PY
then
    bash "$here/lib/venv_install.sh" "$venv" "$o3d_package==$o3d_version" "kiss-matcher==$kiss_version"
fi
export PEERS_COMMAND="${PEERS_COMMAND:-scripts/peers.sh}"
exec "$venv/bin/python" "$here/lib/peers.py" "$@"
