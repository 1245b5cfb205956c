#!/usr/bin/env bash
# Installs what vint needs on a fresh machine: the engines' Python environment (.venv, via
# scripts/setup-python.sh) and the workspace's binaries (dev profile, under target/debug).
# Needs a Rust toolchain (stable, with cargo) and Python 3.13; idempotent, so run it any time.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"

if ! command -v cargo >/dev/null; then
    cat >&2 <<'MSG'
setup: cargo not found. vint needs a stable Rust toolchain: install it with rustup
  (https://rustup.rs), make sure ~/.cargo/bin is on PATH, then run scripts/setup.sh again.
MSG
    exit 1
fi

bash scripts/setup-python.sh
cargo build --workspace --bins
