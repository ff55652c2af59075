#!/usr/bin/env bash
# Installs what cgenreg's tests and GUI need at run time on a fresh Debian machine:
# ffmpeg (test fixtures: libx264 / mpeg4 mp4s), Mesa's software EGL/GL (headless screenshots
# and GUI snapshot tests), g++ (libFuzzer, for scripts/fuzz.sh), Slurm and munge
# (tests/it/slurm.rs starts a single-node Slurm with scripts/slurm-local.sh), and the native
# ONNX Runtime from PyPI (faster VFM; the pure-Rust backend is used when it is absent).
# Safe to run twice.
set -euo pipefail

need_apt=()
command -v ffmpeg >/dev/null 2>&1 || need_apt+=(ffmpeg)
# g++: libfuzzer-sys compiles libFuzzer (C++) for scripts/fuzz.sh's coverage-guided targets.
command -v c++ >/dev/null 2>&1 || need_apt+=(g++)
for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 libgl1 slurm-wlm munge; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
if [ ${#need_apt[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

# Native ONNX Runtime shared library (optional at run time, used when present).
if ! python3 -c 'import onnxruntime' >/dev/null 2>&1; then
  python3 -m pip install -q --disable-pip-version-check onnxruntime==1.31.1 || \
    echo "setup: onnxruntime not installed; the pure-Rust ONNX backend will be used" >&2
fi
