#!/usr/bin/env bash
# One-time setup of a fresh machine: the Debian libraries the Python packages need, then a
# virtual environment with r2s installed in editable mode. Safe to rerun.
set -euo pipefail
VENV="${1:-.venv}"
PYTHON="${PYTHON:-python3}"

# Debian packages: open3d's import needs libusb and the GL/EGL libraries; the tests render
# headless with OSMesa (tests/conftest.py sets PYOPENGL_PLATFORM and MUJOCO_GL to osmesa).
need=()
for pkg in libusb-1.0-0 libgl1 libegl1 libosmesa6; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""
    [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
    echo "installing Debian packages: ${need[*]}"
    $SUDO apt-get update -qq || true
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" || \
      echo "warning: could not install ${need[*]}; rendering features may be unavailable" >&2
  else
    echo "warning: apt-get not found; please install ${need[*]}" >&2
  fi
fi

# Optional: Chromium runs the test of 'r2s view' in a headless browser; that test skips
# (saying why) when it is missing, so setup goes on if it cannot be installed.
if ! command -v chromium >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  SUDO=""
  [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
  echo "installing Debian's chromium (optional, for the viewer's browser test)"
  { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium; } || \
    echo "warning: could not install chromium; the viewer's browser test will be skipped" >&2
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
# torch first and pinned: 2.13.0 is a CPU build available offline; anything else pulls CUDA.
"$VENV/bin/python" -m pip install -q "torch==2.13.0"
# Pinned versions where the lock was made for this Python (results differ with versions).
LOCK=()
if "$VENV/bin/python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  LOCK=(-c "$(cd "$(dirname "$0")/.." && pwd)/requirements-lock.txt")
else
  echo "warning: requirements-lock.txt is for Python 3.11; installing unpinned versions" >&2
fi
"$VENV/bin/python" -m pip install -q "${LOCK[@]}" -e ".[test]"
"$VENV/bin/python" -c "import r2s, torch, open3d, pybullet, trimesh, coacd; print('r2s environment ready')"

# The Khronos glTF validator (npm package gltf-validator) for the export tests; optional:
# without node/npm those tests are skipped with the reason.
if command -v npm >/dev/null 2>&1; then
  mkdir -p .node && npm install --silent --prefix .node gltf-validator || \
    echo "warning: could not install gltf-validator; the glTF validation tests will skip" >&2
else
  echo "warning: npm not found; the glTF validation tests will skip" >&2
fi
