#!/usr/bin/env bash
# Regenerates docs/images/preview.png, README's contact sheet: runs examples/preview.toml (640x480,
# both hands, three objects, one view per grasp) into a scratch directory, then `vintctl preview`
# on it. A few minutes on 2 CPU cores. Run it after a change to the renderer, and commit the image.
#
#   scripts/make_readme_sheet.sh [SCRATCH_DIR]   (default: a fresh temporary directory, removed after)
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
vintctl="${VINTCTL:-$root/target/debug/vintctl}"
if [[ ! -x "$vintctl" ]]; then
    echo "make_readme_sheet: $vintctl not found: build it first (cargo build -p vintctl), or set VINTCTL" >&2
    exit 2
fi
if [[ $# -ge 1 ]]; then
    scratch="$1"
    mkdir -p "$scratch"
else
    scratch="$(mktemp -d -t vint-readme-sheet.XXXXXX)"
    trap 'rm -rf "$scratch"' EXIT
fi

"$vintctl" run examples/preview.toml --out "$scratch/out" --state "$scratch/state"
mkdir -p docs/images
"$vintctl" preview "$scratch/out" --out docs/images/preview.png --samples 4
