#!/usr/bin/env bash
# The test command: every check the project has, against a real Postgres and real engines.
#
#   scripts/test.sh [ARGS...]     ARGS go to `cargo test --workspace` (e.g. a test-name filter)
#
# Sets up the engines' Python environment with the test tools (scripts/setup-python.sh --dev), finds
# a Postgres, then runs cargo fmt, ruff, the deploy manifests' checks, the run-only install's check
# (tests/python/test_install.py), clippy, cargo build (the end-to-end tests start the
# built binaries), the release check (scripts/release_check.sh: one version in Cargo.toml,
# CHANGELOG.md and CITATION.cff; the `cargo package` tarballs of the binaries' crates hold what they
# compile in), cargo test, pytest and every bench's smoke (tests/python/test_bench_smoke.py),
# stopping at the first failure. Nothing is skipped: a missing Postgres, Rust tool, kustomize
# (kubectl), Chromium, jq or engine library is a failure (Postgres, Chromium and jq are
# apt-installed when absent, as root).
#
# Postgres, first that applies:
#   1. $VINT_TEST_POSTGRES_URL, if set (an admin URL: the tests create databases through it);
#   2. the system server on 127.0.0.1:5432, if it accepts `postgres` without a password;
#   3. a throwaway cluster (initdb into a temp dir, a free port, removed on exit), started from the
#      installed PostgreSQL server binaries; on Debian as root these are apt-installed if absent.
# VINT_FORCE_THROWAWAY_PG=1 skips 1 and 2 (to exercise 3 on a machine whose server runs).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"

log() { printf 'test.sh: %s\n' "$*" >&2; }
die() {
    printf '\ntest.sh: ERROR: %s\n' "$*" >&2
    exit 1
}

# --- Rust toolchain ------------------------------------------------------------------------------

require_rust_tools() {
    command -v cargo >/dev/null ||
        die "cargo not found. Install Rust stable (https://rustup.rs) and put ~/.cargo/bin on PATH."
    if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
        command -v rustup >/dev/null ||
            die "cargo fmt and cargo clippy are required; install the rustfmt and clippy components."
        log "installing the rustfmt and clippy components with rustup"
        rustup component add rustfmt clippy ||
            die "could not install the rustfmt and clippy components (rustup component add rustfmt clippy)"
    fi
}

# --- Postgres ------------------------------------------------------------------------------------

# The newest installed PostgreSQL server bin directory (holding initdb), or nothing.
pg_server_bin() {
    local dir
    dir="$(find /usr/lib/postgresql -mindepth 3 -maxdepth 3 -path '*/bin/initdb' 2>/dev/null |
        sort -V | tail -n 1)"
    if [[ -n "$dir" ]]; then
        dirname "$dir"
    elif command -v initdb >/dev/null; then
        dirname "$(readlink -f "$(command -v initdb)")"
    fi
}

# Path of a PostgreSQL client tool: from the server's bin directory if it has one, else PATH.
pg_tool() {
    local bin
    bin="$(pg_server_bin)"
    if [[ -n "$bin" && -x "$bin/$1" ]]; then
        echo "$bin/$1"
    else
        command -v "$1"
    fi
}

# Succeeds if the admin URL accepts a connection (no password prompt; a 5 s connect timeout).
pg_usable() {
    local url="$1" psql
    psql="$(pg_tool psql)" || return 1
    PGCONNECT_TIMEOUT=5 "$psql" --no-password --quiet --tuples-only --dbname "$url" \
        --command 'select 1' >/dev/null 2>&1
}

install_postgres_if_absent() {
    [[ -z "$(pg_server_bin)" ]] || return 0
    if [[ "$(id -u)" -ne 0 ]] || ! command -v apt-get >/dev/null; then
        die "no PostgreSQL server binaries (initdb) found and none can be installed here (needs root and apt-get).
  Install PostgreSQL (Debian: apt-get install postgresql), or point VINT_TEST_POSTGRES_URL at a server."
    fi
    log "!!! No PostgreSQL server binaries found: INSTALLING the Debian package 'postgresql' (apt-get) !!!"
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null; }; then
        die "apt-get install postgresql failed"
    fi
    [[ -n "$(pg_server_bin)" ]] || die "apt-get installed postgresql but no initdb was found"
}

PG_TMP=""
PG_USER=""

# Runs a command as the owner of the throwaway cluster (initdb and postgres refuse to run as root).
as_pg_user() {
    if [[ -z "$PG_USER" ]]; then
        "$@"
    elif command -v runuser >/dev/null; then
        runuser -u "$PG_USER" -- "$@"
    else
        su "$PG_USER" -s /bin/bash -c "$(printf '%q ' "$@")"
    fi
}

stop_throwaway_postgres() {
    [[ -n "$PG_TMP" ]] || return 0
    if [[ -f "$PG_TMP/data/postmaster.pid" ]]; then
        as_pg_user "$(pg_server_bin)/pg_ctl" -D "$PG_TMP/data" -m immediate -w stop >/dev/null 2>&1 || true
    fi
    rm -rf "$PG_TMP"
    PG_TMP=""
}

free_port() {
    "$ROOT/.venv/bin/python" -c \
        'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# Starts a throwaway cluster and sets VINT_TEST_POSTGRES_URL to it; the EXIT trap removes it.
start_throwaway_postgres() {
    install_postgres_if_absent
    local bin port
    bin="$(pg_server_bin)"
    if [[ "$(id -u)" -eq 0 ]]; then
        PG_USER=postgres
        id -u "$PG_USER" >/dev/null 2>&1 || PG_USER=nobody
    fi
    # Under /tmp when the cluster runs as another user: it must reach the directory (and the
    # socket path must stay under ~100 bytes).
    PG_TMP="$(mktemp -d "$([[ -n "$PG_USER" ]] && echo /tmp || echo "${TMPDIR:-/tmp}")/vint-pg.XXXXXX")"
    trap stop_throwaway_postgres EXIT
    trap 'exit 130' INT
    trap 'exit 143' TERM
    [[ -z "$PG_USER" ]] || chown "$PG_USER" "$PG_TMP"
    port="$(free_port)"
    log "starting a throwaway PostgreSQL ($bin) in $PG_TMP on 127.0.0.1:$port${PG_USER:+ as $PG_USER}"
    as_pg_user "$bin/initdb" -D "$PG_TMP/data" -A trust -U postgres -E UTF8 --locale=C --no-sync \
        >"$PG_TMP/initdb.log" 2>&1 || {
        cat "$PG_TMP/initdb.log" >&2
        die "initdb failed (log above)"
    }
    # Durability is pointless for a cluster deleted at exit; max_connections leaves room for the
    # store tests' parallel pools.
    as_pg_user "$bin/pg_ctl" -D "$PG_TMP/data" -l "$PG_TMP/server.log" -w -t 60 \
        -o "-p $port -k $PG_TMP -c listen_addresses=127.0.0.1 -c max_connections=200 -c fsync=off -c synchronous_commit=off -c full_page_writes=off" \
        start >/dev/null || {
        cat "$PG_TMP/server.log" >&2
        die "the throwaway PostgreSQL did not start (server log above)"
    }
    local tries
    for tries in $(seq 60); do
        "$(pg_tool pg_isready)" -q -h 127.0.0.1 -p "$port" && break
        [[ "$tries" -lt 60 ]] || die "the throwaway PostgreSQL never accepted connections"
        sleep 0.5
    done
    VINT_TEST_POSTGRES_URL="postgres://postgres@127.0.0.1:$port/postgres"
}

choose_postgres() {
    local system_url="postgres://postgres@127.0.0.1:5432/postgres"
    if [[ "${VINT_FORCE_THROWAWAY_PG:-0}" == 1 ]]; then
        log "VINT_FORCE_THROWAWAY_PG=1: using a throwaway cluster"
        start_throwaway_postgres
    elif [[ -n "${VINT_TEST_POSTGRES_URL:-}" ]]; then
        pg_usable "$VINT_TEST_POSTGRES_URL" ||
            die "VINT_TEST_POSTGRES_URL=$VINT_TEST_POSTGRES_URL does not accept connections"
    elif pg_usable "$system_url"; then
        VINT_TEST_POSTGRES_URL="$system_url"
    else
        log "no usable Postgres on 127.0.0.1:5432"
        start_throwaway_postgres
    fi
    pg_usable "$VINT_TEST_POSTGRES_URL" || die "Postgres at $VINT_TEST_POSTGRES_URL is not usable"
    log "Postgres: $VINT_TEST_POSTGRES_URL"
}

# Succeeds if process PID exists (also one of another user, which kill -0 cannot signal).
pid_alive() {
    kill -0 "$1" 2>/dev/null || [[ -d "/proc/$1" ]] || ps -p "$1" >/dev/null 2>&1
}

# The test process id in a test database's name, or nothing. The tests name their databases
# vint_test_<pid>_<tag>_<nanos>_<n> (tests/src/lib.rs postgres_database, services/store/tests/
# common/mod.rs); names from before that order was fixed put a tag first (vint_test_<tag>_<pid>_<n>),
# and other checkouts may still create them, so a non-numeric first field defers to the second.
test_database_pid() {
    local rest="${1#vint_test_}" first second
    first="${rest%%_*}"
    rest="${rest#*_}"
    second="${rest%%_*}"
    if [[ "$first" =~ ^[0-9]+$ ]]; then
        echo "$first"
    elif [[ "$second" =~ ^[0-9]+$ ]]; then
        echo "$second"
    fi
}

# Drops the per-test databases (vint_test_<pid>_…) of earlier runs. Databases in use, or whose
# test process still lives, are left alone: another run may be using them.
drop_stale_test_databases() {
    local psql name pid dropped=0
    psql="$(pg_tool psql)"
    while read -r name; do
        [[ -n "$name" ]] || continue
        pid="$(test_database_pid "$name")"
        if [[ -n "$pid" ]] && pid_alive "$pid"; then
            continue
        fi
        # Without FORCE, DROP DATABASE fails on a database that has connections: left alone.
        if "$psql" --no-password --quiet --dbname "$VINT_TEST_POSTGRES_URL" \
            --command "DROP DATABASE IF EXISTS \"$name\"" >/dev/null 2>&1; then
            dropped=$((dropped + 1))
        fi
    done < <("$psql" --no-password --tuples-only --no-align --dbname "$VINT_TEST_POSTGRES_URL" \
        --command "SELECT datname FROM pg_database WHERE datname LIKE 'vint\_test\_%'" 2>/dev/null || true)
    [[ "$dropped" -eq 0 ]] || log "dropped $dropped stale test database(s)"
}

# --- tools from Debian's packages: headless Chromium, jq ----------------------------------------

# Command TOOL on PATH, else Debian's PACKAGE installed with apt-get (as root), else a failure whose
# message ends with HINT.
require_debian_tool() {
    local tool="$1" package="$2" hint="$3"
    command -v "$tool" >/dev/null && return 0
    if [[ "$(id -u)" -ne 0 ]] || ! command -v apt-get >/dev/null; then
        die "$tool not found and it cannot be installed here (needs root and apt-get).
  $hint"
    fi
    log "!!! $tool not found: INSTALLING the Debian package '$package' (apt-get) !!!"
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$package" >/dev/null 2>&1; then
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$package" >/dev/null ||
            die "apt-get install $package failed"
    fi
    command -v "$tool" >/dev/null || die "apt-get installed $package but $tool is not on PATH"
}

# Chromium for tests/tests/dashboard.rs: $VINT_CHROMIUM, else `chromium` on PATH, else Debian's
# package.
require_chromium() {
    if [[ -n "${VINT_CHROMIUM:-}" ]]; then
        [[ -x "$VINT_CHROMIUM" ]] || die "VINT_CHROMIUM=$VINT_CHROMIUM is not an executable"
        return 0
    fi
    require_debian_tool chromium chromium \
        "Install Debian's chromium package, or set VINT_CHROMIUM to a Chromium or Chrome binary."
}

# --- steps ---------------------------------------------------------------------------------------

# deploy/: every kustomize overlay rendered (kubectl >= 1.27 or kustomize v5 on PATH) and checked
# against the Kubernetes API schemas and the platform rules; then the checker's own tests.
deploy_checks() {
    .venv/bin/python scripts/validate_deploy.py &&
        .venv/bin/python -m pytest tests/python/test_validate_deploy.py -q
}

STEP=0
STEPS=11

# Runs one check with a banner and its elapsed time; the first failure ends the script.
step() {
    local name="$1" started status=0
    shift
    STEP=$((STEP + 1))
    printf '\n==> [%d/%d] %s\n' "$STEP" "$STEPS" "$name" >&2
    started=$SECONDS
    "$@" || status=$?
    if [[ "$status" -ne 0 ]]; then
        printf '<== [%d/%d] %s FAILED (exit %d) after %ds\n' "$STEP" "$STEPS" "$name" "$status" \
            $((SECONDS - started)) >&2
        exit "$status"
    fi
    printf '<== [%d/%d] %s ok (%ds)\n' "$STEP" "$STEPS" "$name" $((SECONDS - started)) >&2
}

require_rust_tools
started=$SECONDS
bash scripts/setup-python.sh --dev
log "Python environment ready ($((SECONDS - started))s)"

choose_postgres
drop_stale_test_databases
require_chromium
# jq for benches/queue.sh's smoke (the bench smokes step).
require_debian_tool jq jq "Install Debian's jq package."
export VINT_TEST_POSTGRES_URL
export VINT_PYTHON="$ROOT/.venv/bin/python"
export VINT_REQUIRE_ENGINES=1

total=$SECONDS
# Cheap checks first, so a formatting slip fails in seconds rather than after a build.
step "cargo fmt --check" cargo fmt --all -- --check
step "ruff check" .venv/bin/ruff check workers/engines benches scripts examples tests/python
step "ruff format --check" .venv/bin/ruff format --check workers/engines benches scripts examples tests/python
step "deploy manifests" deploy_checks
# README command 1 installs what a run needs and no test-only package (a fresh venv, from pip's cache).
step "install" .venv/bin/python -m pytest tests/python/test_install.py -q
step "cargo clippy" cargo clippy --workspace --all-targets -- -D warnings
step "cargo build --bins" cargo build --workspace --bins
# After the build, so that the crates.io index cargo package reads is at hand; without --verify,
# which would build every crate again from its tarball (scripts/release_check.sh says why not here).
step "release check" bash scripts/release_check.sh
step "cargo test" cargo test --workspace "$@"
step "pytest (engines)" .venv/bin/python -m pytest workers/engines/tests -q --durations=15
step "bench smokes" .venv/bin/python -m pytest tests/python/test_bench_smoke.py tests/python/test_packed_outputs.py tests/python/test_dispatch_report.py -q --durations=0
printf '\ntest.sh: all %d checks passed in %ds\n' "$STEPS" $((SECONDS - total)) >&2
