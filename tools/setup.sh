#!/usr/bin/env bash
# Create .venv and install leovr with everything it needs, on a fresh machine of this kind.
# Idempotent: re-running only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3

# Open3D needs libusb-1.0 at import time.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  echo "setup: installing libusb-1.0-0 (needed by Open3D)"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# pip, quietly, without the index-location warnings this machine's pip config prints; keep pip's exit code.
pipq() {
  .venv/bin/pip install -q --disable-pip-version-check "$@" 2>&1 | { grep -v "is ignored: it is neither a file nor a directory" || true; }
  return "${PIPESTATUS[0]}"
}
stamp=.venv/.leovr-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  # torch first, spelled exactly, so pip takes the CPU build on disk instead of a CUDA build.
  pipq torch==2.13.0
  pipq -e ".[test]"
  touch "$stamp"
fi
.venv/bin/python -c "import leovr, gtsam, open3d, kiss_icp, rerun, torch, cv2, evo, ray, threadpoolctl, onnx, onnxruntime, rosbags.highlevel" \
  || { echo "setup: import check failed" >&2; exit 1; }
echo "setup: ok (.venv)"
