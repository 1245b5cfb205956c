#!/usr/bin/env bash
# Creates (or refreshes) the Python environment of the engines at <repo>/.venv.
#
# bpy 5.2.x wheels exist only for Python 3.13, so the engines need a Python 3.13 interpreter:
# $VINT_BASE_PYTHON if set, else python3.13 on PATH, else a pyenv 3.13 install, else python3 if it is 3.13.
# Installs workers/engines/requirements.lock and requirements-dev.lock (exact pins). Idempotent: a
# stamp in .venv holds the locks' sha256, and a matching stamp skips the install. The dev lock holds
# torch for the WebDataset loader example: PyPI's Linux build, whose CUDA libraries it cannot import
# without (~2.8 GB to download, ~5.3 GB installed; the example runs on the CPU).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="$ROOT/.venv"
ENGINES="$ROOT/workers/engines"
LOCKS=("$ENGINES/requirements.lock" "$ENGINES/requirements-dev.lock")
STAMP="$VENV/.vint-lock.sha256"

log() { printf 'setup-python: %s\n' "$*" >&2; }

# Prints the interpreter's path if it runs and is Python 3.13 (pyenv shims may exist but not run).
is_py313() {
    local candidate="$1"
    [[ -n "$candidate" ]] || return 1
    "$candidate" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 13) else 1)' >/dev/null 2>&1
}

find_python() {
    local candidate
    if [[ -n "${VINT_BASE_PYTHON:-}" ]]; then
        if is_py313 "$VINT_BASE_PYTHON"; then
            echo "$VINT_BASE_PYTHON"
            return 0
        fi
        log "VINT_BASE_PYTHON=$VINT_BASE_PYTHON is not a working Python 3.13 interpreter"
        return 1
    fi
    candidate="$(command -v python3.13 || true)"
    if is_py313 "$candidate"; then
        echo "$candidate"
        return 0
    fi
    for candidate in /root/.pyenv/versions/3.13*/bin/python3.13; do
        if is_py313 "$candidate"; then
            echo "$candidate"
            return 0
        fi
    done
    candidate="$(command -v python3 || true)"
    if is_py313 "$candidate"; then
        echo "$candidate"
        return 0
    fi
    return 1
}

if ! PYTHON="$(find_python)"; then
    cat >&2 <<'EOF'
setup-python: no Python 3.13 interpreter found.
  The engines need Python 3.13: bpy 5.2.x (Blender as a Python module) publishes wheels for
  Python 3.13 only. Install Python 3.13 (e.g. `pyenv install 3.13`) and either put python3.13 on
  PATH or point VINT_BASE_PYTHON at it, then run this script again.
EOF
    exit 1
fi
log "using $PYTHON ($("$PYTHON" --version 2>&1))"

lock_hash() { cat "${LOCKS[@]}" | sha256sum | cut -d' ' -f1; }

venv_matches() {
    [[ -x "$VENV/bin/python" ]] && is_py313 "$VENV/bin/python" &&
        [[ -f "$STAMP" ]] && [[ "$(cat "$STAMP")" == "$(lock_hash)" ]]
}

if venv_matches; then
    log ".venv already matches the locks; skipping install"
else
    if [[ -x "$VENV/bin/python" ]] && ! is_py313 "$VENV/bin/python"; then
        log ".venv holds another Python version; recreating it"
        rm -rf "$VENV"
    fi
    if [[ ! -x "$VENV/bin/python" ]]; then
        log "creating $VENV"
        "$PYTHON" -m venv "$VENV"
    fi
    rm -f "$STAMP"
    log "installing pinned packages (bpy ~400 MB and torch with its CUDA libraries ~2.8 GB to download the first time)"
    "$VENV/bin/python" -m pip install --disable-pip-version-check --quiet \
        -r "$ENGINES/requirements.lock" -r "$ENGINES/requirements-dev.lock"
    lock_hash >"$STAMP"
fi

"$VENV/bin/python" - <<'EOF'
import platform

import bpy
import cv2
import mujoco
import numpy
import torch
import webdataset

print(f"python {platform.python_version()}")
print(f"bpy    {bpy.app.version_string}")
print(f"mujoco {mujoco.__version__}")
print(f"opencv {cv2.__version__}")
print(f"numpy  {numpy.__version__}")
print(f"torch  {torch.__version__} (webdataset {webdataset.__version__})")
EOF
log "ready: run the engine tests with .venv/bin/python -m pytest workers/engines/tests -q"
