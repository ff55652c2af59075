#!/usr/bin/env bash
# SpinNet (the learned geometric branch): its ONNX exports and the parity dumps its tests read are
# made from the authors' research-only checkpoints (../shared/models/spinnet) by
# models/spinnet_export.sh (torch in a scratch venv under target/, a few minutes) into
# target/spinnet; never committed. Under CI=true its tests fail without them, so CI makes them;
# elsewhere CGENREG_SPINNET=1 asks for them.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${CI:-}" = "true" ] || [ "${CGENREG_SPINNET:-}" = "1" ]; then
  if [ -d ../shared/models/spinnet ] && [ ! -s target/spinnet/parity-kitti.npz ]; then
    bash models/spinnet_export.sh --keypoints 4 ||
      echo "setup: the SpinNet export failed; the SpinNet tests fail under CI=true without it" >&2
  fi
fi
