#!/usr/bin/env bash
# Install Python packages into a private virtual environment (made if missing):
#   bash scripts/lib/venv_install.sh VENV PACKAGE...
# With uv (pinned below, itself installed once into its own venv under the build folder) when
# it can be had: it unpacks the test tools' wheels (torch's 3 GB among them) in a third less
# CPU time than pip and in under half the wall time (docs/development.md). Otherwise, or if
# uv fails, with the venv's own pip. The system Python and its pip are never touched, and no
# download cache is kept outside the build folder.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
venv="$1"
shift
target="${CARGO_TARGET_DIR:-$root/target}"
uv_version="0.13.9"
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv" || {
    echo "venv_install: 'python3 -m venv $venv' failed (Debian/Ubuntu: apt-get install python3-venv)" >&2
    exit 1
  }
fi
uv_venv="$target/uv-venv"
uv="$uv_venv/bin/uv"
if [ ! -x "$uv" ] || [ "$("$uv" --version 2>/dev/null)" != "uv $uv_version" ]; then
  { python3 -m venv "$uv_venv" &&
    "$uv_venv/bin/python" -m pip install -q --disable-pip-version-check --no-cache-dir \
      "uv==$uv_version"; } >/dev/null 2>&1 || true
fi
# The cache sits beside the venvs so that uv links the unpacked files instead of copying them.
if [ -x "$uv" ] && UV_CACHE_DIR="$target/uv-cache" "$uv" pip install --quiet \
  --python "$venv/bin/python" "$@"; then
  exit 0
fi
echo "venv_install: uv unavailable or failed; installing with pip" >&2
exec "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-cache-dir "$@"
