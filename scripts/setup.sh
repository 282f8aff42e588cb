#!/usr/bin/env bash
# Create or refresh .venv with the project and its dependencies (CPU-only PyTorch).
# Installs the system library libusb-1.0-0 that open3d needs when it is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-python3}"

# grep reads the whole list (no -q): with pipefail, -q's early exit can kill ldconfig with SIGPIPE and
# make a present library look missing (measured: 4 of 200 checks here)
if ! ldconfig -p 2>/dev/null | grep 'libusb-1.0.so.0' >/dev/null; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
        echo "setup: installing libusb-1.0-0 (needed by open3d)"
        apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "setup: open3d needs the system library libusb-1.0-0; install it (e.g. 'sudo apt-get install libusb-1.0-0') and re-run" >&2
        exit 1
    fi
fi

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv"
    "$PY" -m venv .venv
fi
stamp=.venv/.mvracklay-installed
# A .venv moved with its folder keeps the old place in its entry points ("cannot execute: required file
# not found") and its editable install: install the project again.
if [ -f "$stamp" ] && [ -f .venv/bin/mvracklay ]; then
    case "$(head -1 .venv/bin/mvracklay)" in
        "#!$PWD/.venv/"*) ;;
        *) echo "setup: .venv was made in another folder; reinstalling the project"; rm -f "$stamp" ;;
    esac
fi
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ scripts/setup.sh -nt "$stamp" ]; then
    echo "setup: installing the project into .venv (first run takes a few minutes)"
    .venv/bin/python -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
    # CPU build of PyTorch first, so nothing pulls a multi-GB CUDA build.
    .venv/bin/python -m pip install -q torch==2.13.0 2>&1 | grep -v '^WARNING: Location' || true
    # with Ray (the `ray` extra) for `--ray ADDRESS`: about 80 MB to download, 240 MB installed
    .venv/bin/python -m pip install -q -e '.[dev,ray]' 2>&1 | grep -v '^WARNING: Location' || true
    .venv/bin/python -c "import torch, open3d, trimesh, rerun, skimage, onnx, onnxruntime, ray" || { echo "setup: install failed" >&2; exit 1; }
    touch "$stamp"
fi

# The Khronos glTF validator (npm) for the .glb conformance test; skipped where node is absent.
if command -v npm >/dev/null 2>&1 && [ -f package-lock.json ]; then
    if [ ! -d node_modules/gltf-validator ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
        echo "setup: installing the glTF validator (npm ci)"
        npm ci --no-audit --no-fund --silent 2>&1 | grep -v 'Unknown user config' || true
        [ -d node_modules/gltf-validator ] || echo "setup: npm ci failed; the glTF validator test will be skipped" >&2
    fi
fi
