#!/usr/bin/env bash
# Creates (or refreshes) the Python environment of the engines at <repo>/.venv.
#
#   scripts/setup-python.sh          what a run needs: workers/engines/requirements.lock (the engines,
#                                    and the plots of `vintctl stats` and `vintctl study`)
#   scripts/setup-python.sh --dev    that, plus requirements-dev.lock: the test and lint tools, the S3
#                                    test server, the deploy check, and torch for the WebDataset loader
#                                    example's test (PyPI's Linux build, whose CUDA libraries it cannot
#                                    import without: ~2.8 GB to download, ~5.3 GB installed)
#
# bpy 5.2.x wheels exist only for Python 3.13, so the engines need a Python 3.13 interpreter:
# $VINT_BASE_PYTHON if set, else python3.13 on PATH, else a pyenv 3.13 install, else python3 if it is 3.13.
# Both locks are exact pins. Idempotent: a stamp in .venv per lock holds its sha256, and a matching
# stamp skips that lock's install.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="${VINT_VENV:-$ROOT/.venv}"  # another place only for the install test (tests/python/test_install.py)
ENGINES="$ROOT/workers/engines"
RUNTIME_LOCK="$ENGINES/requirements.lock"
DEV_LOCK="$ENGINES/requirements-dev.lock"
RUNTIME_STAMP="$VENV/.vint-lock.sha256"
DEV_STAMP="$VENV/.vint-dev-lock.sha256"

DEV=0
case "${1:-}" in
    "") ;;
    --dev) DEV=1 ;;
    *)
        printf 'setup-python: unknown argument %q (usage: scripts/setup-python.sh [--dev])\n' "$1" >&2
        exit 2
        ;;
esac

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

lock_hash() { sha256sum "$1" | cut -d' ' -f1; }

# Succeeds if the stamp $2 records the lock $1 as installed.
stamped() { [[ -f "$2" ]] && [[ "$(cat "$2")" == "$(lock_hash "$1")" ]]; }

if [[ -x "$VENV/bin/python" ]] && ! is_py313 "$VENV/bin/python"; then
    log ".venv holds another Python version; recreating it"
    rm -rf "$VENV"
fi
if [[ ! -x "$VENV/bin/python" ]]; then
    log "creating $VENV"
    "$PYTHON" -m venv "$VENV"
    rm -f "$RUNTIME_STAMP" "$DEV_STAMP"
fi

# Installs the lock $1 unless the stamp $2 records it; the dev lock is installed with the runtime
# one, so that pip keeps every runtime pin.
install_lock() {
    local lock="$1" stamp="$2" what="$3"
    if stamped "$lock" "$stamp"; then
        log ".venv already holds $(basename "$lock"); skipping it"
        return 0
    fi
    rm -f "$stamp"
    local args=(-r "$RUNTIME_LOCK")
    if [[ "$lock" == "$DEV_LOCK" ]]; then
        args+=(-r "$DEV_LOCK")
    fi
    log "installing $(basename "$lock"): $what"
    "$VENV/bin/python" -m pip install --disable-pip-version-check --quiet "${args[@]}"
    lock_hash "$lock" >"$stamp"
}

install_lock "$RUNTIME_LOCK" "$RUNTIME_STAMP" "the engines and the plots (bpy ~400 MB to download the first time)"
if [[ "$DEV" == 1 ]]; then
    install_lock "$DEV_LOCK" "$DEV_STAMP" \
        "test and lint tools, and torch with its CUDA libraries (~2.8 GB to download the first time)"
fi

"$VENV/bin/python" - "$DEV" <<'EOF'
import platform
import sys

import bpy
import cv2
import matplotlib
import mujoco
import numpy

print(f"python     {platform.python_version()}")
print(f"bpy        {bpy.app.version_string}")
print(f"mujoco     {mujoco.__version__}")
print(f"opencv     {cv2.__version__}")
print(f"numpy      {numpy.__version__}")
print(f"matplotlib {matplotlib.__version__}")
if sys.argv[1] == "1":
    import pytest
    import torch
    import webdataset

    print(f"pytest     {pytest.__version__}")
    print(f"torch      {torch.__version__} (webdataset {webdataset.__version__})")
EOF
if [[ "$DEV" == 1 ]]; then
    log "ready: run the engine tests with .venv/bin/python -m pytest workers/engines/tests -q"
else
    log "ready to run datasets; for the tests and lint tools: scripts/setup-python.sh --dev"
fi
