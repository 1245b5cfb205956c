#!/usr/bin/env bash
# The release check: one version everywhere, and crates that hold every file they compile in.
#
#   scripts/release_check.sh [--verify]
#
# 1. tests/python/test_release.py: Cargo.toml's version is every crate's, CITATION.cff's and that of
#    CHANGELOG.md's newest section; LICENSE is the licence Cargo.toml names.
# 2. `cargo package` of the ten crates the binaries (vintctl, vint-coordinator, vint-worker) are
#    built from, together: cargo (1.90+) puts the crates it packages in a local registry laid over
#    crates.io, so each resolves its vint-* dependencies to the packages beside it.
# 3. scripts/check_packages.py reads the tarballs: every file the crates' library and binary code
#    compiles in (include_str!, include_bytes!, sqlx::migrate!) is inside its package, and the
#    packages of the crates that link a root directory in hold all of it (vint-proto: proto/,
#    vint-store: migrations/, vint-core: catalog/).
#
# --verify also lets cargo build each crate from its unpacked tarball alone, as `cargo install`
# from a registry would. Each crate alone enables other features of its dependencies than the
# workspace's build does, so cargo compiles them again, per crate: on the shared 2-core machine where
# the workspace's build took 39 minutes, the first crate's verification began by rebuilding syn and
# serde and was stopped after about 3 minutes; it has not been run to the end. The test command, and
# so CI, runs the check without it; cutting a release runs it with (docs/operations.md).
#
# Uncommitted changes are packaged too (--allow-dirty): the check runs on a working tree in
# scripts/test.sh, and a release is cut from a commit that passed it.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"

log() { printf 'release_check.sh: %s\n' "$*" >&2; }
die() {
    printf '\nrelease_check.sh: ERROR: %s\n' "$*" >&2
    exit 1
}

verify=(--no-verify)
case "${1:-}" in
    "") ;;
    --verify) verify=() ;;
    *) die "unknown argument ${1}: the only option is --verify (build each package)" ;;
esac

PYTHON="$ROOT/.venv/bin/python"
[[ -x "$PYTHON" ]] || die "$PYTHON not found: set up the Python environment first (scripts/setup-python.sh --dev)"

# The crates the three binaries are built from: every member of the workspace but the tests'.
CRATES=(vint-core vint-proto vint-store vint-artifacts vint-telemetry vint-connect vint-engine-env
    vint-coordinator vint-runtime vintctl)

started=$SECONDS
"$PYTHON" -m pytest tests/python/test_release.py -q
version="$("$PYTHON" -c 'import tomllib; print(tomllib.load(open("Cargo.toml", "rb"))["workspace"]["package"]["version"])')"
log "version $version: Cargo.toml, the crates, CITATION.cff and CHANGELOG.md agree ($((SECONDS - started))s)"

packages=()
for crate in "${CRATES[@]}"; do
    packages+=(--package "$crate")
done
# With --verify, the workspace's dev profile for the builds (a packaged manifest carries none), vint's
# crates at opt-level 0 as in the workspace: to cargo they are now registry crates, under "*".
profile=(
    --config 'profile.dev.debug="line-tables-only"'
    --config 'profile.dev.package."*".opt-level=2'
    --config 'profile.dev.package."*".debug=false'
)
for crate in "${CRATES[@]}"; do
    profile+=(--config "profile.dev.package.$crate.opt-level=0")
    profile+=(--config "profile.dev.package.$crate.debug=\"line-tables-only\"")
done

started=$SECONDS
cargo package --locked --allow-dirty "${verify[@]}" "${profile[@]}" "${packages[@]}"
log "cargo package ${verify[*]}: ${#CRATES[@]} crates ($((SECONDS - started))s)"

target_dir="$(cargo metadata --format-version 1 --no-deps --locked |
    "$PYTHON" -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')"
"$PYTHON" scripts/check_packages.py "$target_dir/package" "$version" "${CRATES[@]}"
log "ok: the release check of $version passed"
