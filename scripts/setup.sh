#!/usr/bin/env bash
# Installs what cgenreg's tests and GUI need at run time on a fresh Debian or Ubuntu machine.
# Safe to run twice.
#
# System packages (apt, needs root: run as root or with sudo available):
#   ffmpeg            test fixtures (libx264 / mpeg4 mp4s)
#   Mesa EGL/GL       headless screenshots and the GUI snapshot tests (software rendering)
#   g++               libFuzzer for scripts/fuzz.sh
#   slurm-wlm, munge  tests/it/slurm.rs starts a single-node Slurm (scripts/slurm-local.sh);
#                     the daemons start jobs as their user, so that test also needs root
#   python3-venv      the private venv below
# Without root and without sudo the missing packages are named and the script goes on.
#
# The native ONNX Runtime (the fast backend for XFeat, DISK, ALIKE and MASt3R exports) goes
# into a private venv in the build folder, ${CARGO_TARGET_DIR:-target}/ortvenv: the system
# Python is never touched (PEP 668 "externally managed" Pythons refuse `pip install`). cgenreg
# finds the library there by itself (beside its own binary); scripts/test.sh also exports
# ORT_DYLIB_PATH. Without it the pure-Rust backend is used (slower, same results).
set -euo pipefail
cd "$(dirname "$0")/.."

ORT_VERSION=1.31.1

need_apt=()
command -v ffmpeg >/dev/null 2>&1 || need_apt+=(ffmpeg)
command -v c++ >/dev/null 2>&1 || need_apt+=(g++)
for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 libgl1 slurm-wlm munge; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
# `python3 -m venv` needs ensurepip, which Debian ships in python3-venv.
if ! python3 -I -c 'import ensurepip, venv' >/dev/null 2>&1; then need_apt+=(python3-venv); fi
if [ ${#need_apt[@]} -gt 0 ]; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else SUDO="none"; fi
  fi
  if [ "$SUDO" = "none" ]; then
    echo "setup: not root and no sudo; install these packages as root: ${need_apt[*]}" >&2
  else
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
  fi
fi
if [ "$(id -u)" -ne 0 ]; then
  echo "setup: not root: the local-Slurm test cannot start its daemons (under CI=true it fails; run the tests as root)" >&2
fi

# Native ONNX Runtime in a private venv (optional at run time, used when present). With an
# NVIDIA GPU (`nvidia-smi -L` lists one) or CGENREG_ORT_GPU=1: the onnxruntime-gpu build with
# the CUDA and cuDNN wheels it names, so the ONNX models run on the GPU (CGENREG_ORT_GPU=0
# keeps the CPU build; CGENREG_ORT_PROVIDER=cpu keeps a GPU build on the CPU at run time).
venv="${CARGO_TARGET_DIR:-target}/ortvenv"
ort_lib() { compgen -G "$venv/lib/python3*/site-packages/onnxruntime/capi/libonnxruntime.so*" | sort | tail -n 1; }
ort_pkg="onnxruntime==$ORT_VERSION"
if [ "${CGENREG_ORT_GPU:-}" = 1 ] ||
  { [ "${CGENREG_ORT_GPU:-}" != 0 ] && nvidia-smi -L 2>/dev/null | grep -q '^GPU'; }; then
  ort_pkg="onnxruntime-gpu[cuda,cudnn]==$ORT_VERSION"
fi
if [ -z "$(ort_lib || true)" ]; then
  mkdir -p "$(dirname "$venv")"
  if python3 -m venv "$venv" >/dev/null 2>&1 &&
    "$venv/bin/python" -m pip install -q --disable-pip-version-check "$ort_pkg"; then
    echo "setup: $ort_pkg installed in $venv"
  else
    echo "setup: $ort_pkg not installed in $venv; the pure-Rust ONNX backend will be used" >&2
  fi
fi

# SpinNet's exports (under CI=true, or with CGENREG_SPINNET=1): models/spinnet_prepare.sh.
# scripts/test.sh sets CGENREG_SETUP_SKIP_SPINNET=1 and runs it in the background during the build.
if [ "${CGENREG_SETUP_SKIP_SPINNET:-}" != "1" ]; then
  bash models/spinnet_prepare.sh
fi
