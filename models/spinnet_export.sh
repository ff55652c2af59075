#!/usr/bin/env bash
# Export SpinNet's network (after the patch grouping) to ONNX and dump the authors' grouped
# patches for the Rust parity test: a scratch venv under target/ with torch from PyPI (run on
# the CPU), never the system pip. Arguments go to models/spinnet_export.py (see its --help).
# Outputs land in target/spinnet/ (SPINNET_OUT to change): the weights are research-only, so
# neither they nor their export is ever committed.
#   SPINNET_VENV   the venv (default target/spinnet-venv)
#   SPINNET_TIMEOUT  seconds before the export is stopped (default 1800)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${SPINNET_VENV:-$root/target/spinnet-venv}"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import torch, onnx, onnxruntime' 2>/dev/null; then
    # Not byte-compiled: torch's thousands of modules are compiled on first import instead.
    bash "$root/scripts/lib/venv_install.sh" "$venv" \
        'torch==2.15.0' 'onnx==1.23.2' 'onnxruntime==1.31.1' numpy
fi
out="${SPINNET_OUT:-$root/target/spinnet}"
exec timeout "${SPINNET_TIMEOUT:-1800}" "$venv/bin/python" "$root/models/spinnet_export.py" --out-dir "$out" "$@"
