#!/usr/bin/env bash
# The queue bench: the coordinator over gRPC beside what its database can do and beside a peer queue,
# measured in one invocation on the same Postgres, rounds interleaved so the machine's load touches all
# three alike:
#
#   ceiling      the raw SQL lease + complete (../shared/peers/pg-ceiling: pgbench, 64 tasks per
#                transaction, 2 clients; tasks/s = tps x 64), on a fresh scratch database each round
#   coordinator  benches/coordinator.rs (release build): no-op workers over gRPC, LeaseTasks(batch) then
#                one CompleteTasks per lease, on Postgres and SQLite
#   awa          awa 0.6.9 draining 100,000 no-op jobs with 1,024 workers (../shared/peers/awa-bench,
#                built from a copy under target/peers so nothing of it lands in the repository)
#
#   benches/queue.sh [COORDINATOR_FILTER...]      e.g. benches/queue.sh postgres/batch64
#   VINT_BENCH_SMOKE=1 benches/queue.sh
#
# Prints each round as it goes, then every case's median, min and max over the rounds, the ratios
# coordinator / ceiling and coordinator / awa, and one JSON line per case. Every run's JSON line is
# also kept in target/queue-bench/<time>.jsonl.
#
# Settings (environment): VINT_TEST_POSTGRES_URL (admin URL, default postgres://postgres@127.0.0.1:5432/postgres),
# VINT_PEERS_DIR (default: the repository's ../shared/peers), VINT_QUEUE_ROUNDS (3), VINT_QUEUE_CEILING_S
# (pgbench duration, 15), VINT_QUEUE_AWA_JOBS (100000); the coordinator's own knobs (VINT_BENCH_TASKS,
# VINT_BENCH_WORKERS, VINT_BENCH_PREFETCH) pass through to it. CARGO_BUILD_JOBS applies to both builds.
#
# The smoke (VINT_BENCH_SMOKE=1; seconds: the test command's check that the bench still runs, not a
# figure) runs what needs neither the peers nor a release build, which the test command cannot
# assume: one round (VINT_QUEUE_ROUNDS) of the coordinator cases alone, from the dev build of
# benches/coordinator.rs with 64 tasks per run (VINT_BENCH_TASKS), then the summary and ratios as
# always (n/a for the missing ceiling and awa). It checks the settings, the coordinator's JSON lines
# against this script's jq and the summary; not pgbench, the peers' scripts or awa. Its JSON lines go
# to a temporary directory, removed at exit. It needs psql, jq, cargo and Postgres.
set -euo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
admin=${VINT_TEST_POSTGRES_URL:-postgres://postgres@127.0.0.1:5432/postgres}
peers=${VINT_PEERS_DIR:-$(dirname "$repo")/shared/peers}
smoke=${VINT_BENCH_SMOKE:-0}
if [[ $smoke == 1 ]]; then
  rounds=${VINT_QUEUE_ROUNDS:-1}
  export VINT_BENCH_TASKS=${VINT_BENCH_TASKS:-64}
  bench_profile=dev
else
  rounds=${VINT_QUEUE_ROUNDS:-3}
  bench_profile=bench
fi
ceiling_s=${VINT_QUEUE_CEILING_S:-15}
awa_jobs=${VINT_QUEUE_AWA_JOBS:-100000}
awa_workers=1024          # awa-bench's best configuration on this machine kind (its README)
# The coordinator's no-op workers: as many as the ceiling's pgbench clients (2), each with its next
# lease in flight while it completes the last; more only queue on the same two cores (4 workers:
# ~10 % fewer tasks/s here).
export VINT_BENCH_WORKERS=${VINT_BENCH_WORKERS:-2}
ceiling_batch=64          # tasks per transaction in lease_batch64.pgb
ceiling_rows_per_s=100000 # rows loaded per second of pgbench: headroom over the ~57k tasks/s measured
ceiling_db=vint_bench_ceiling
awa_db=vint_bench_awa

die() { echo "queue bench: $*" >&2; exit 2; }

# All three speak to Postgres in clear. The server here has ssl = on, and libpq's and sqlx's default
# (sslmode=prefer) would encrypt pgbench's and awa's loopback connections while the coordinator, on
# a loopback URL naming no sslmode, connects in clear (vint_store::postgres_url): TLS cost the
# coordinator a quarter of its batch-256 rate (docs/benchmarks.md), so the same handicap on one side
# only would skew the ratios. PGSSLMODE is read by psql, pgbench, sqlx and vint_store alike.
export PGSSLMODE=${PGSSLMODE:-disable}

# A setting must be a whole number within bounds: name, value, min, max.
check_count() {
  [[ $2 =~ ^[0-9]+$ ]] && (($2 >= $3 && $2 <= $4)) || die "$1 = '$2': must be an integer from $3 to $4"
}
[[ $smoke == 0 || $smoke == 1 ]] || die "VINT_BENCH_SMOKE = '$smoke': must be 0 or 1"
check_count VINT_QUEUE_ROUNDS "$rounds" 1 100
check_count VINT_QUEUE_CEILING_S "$ceiling_s" 1 600
check_count VINT_QUEUE_AWA_JOBS "$awa_jobs" 1000 10000000

if ((!smoke)); then
  [[ -f $peers/pg-ceiling/lease_batch64.pgb && -f $peers/pg-ceiling/schema.sql && -f $peers/pg-ceiling/load_n.sql ]] ||
    die "the raw SQL ceiling's scripts are missing: expected $peers/pg-ceiling/{schema.sql,load_n.sql,lease_batch64.pgb} (the repository's ../shared/peers; set VINT_PEERS_DIR to point elsewhere)"
  [[ -f $peers/awa-bench/Cargo.toml && -d $peers/awa-bench/src ]] ||
    die "the awa harness is missing: expected $peers/awa-bench/{Cargo.toml,src/} (the repository's ../shared/peers; set VINT_PEERS_DIR to point elsewhere)"
  command -v pgbench >/dev/null || die "'pgbench' is not on PATH (Debian's postgresql-client-15)"
fi
for tool in psql jq cargo; do
  command -v "$tool" >/dev/null || die "'$tool' is not on PATH (psql: Debian's postgresql-client-15; jq: jq)"
done

# The admin URL with another database in its path.
db_url() { echo "${admin%/*}/$1"; }
# psql without its NOTICEs (DROP ... IF EXISTS talks); errors still stop it and reach stderr.
quiet_psql() { PGOPTIONS="-c client_min_messages=warning" psql -v ON_ERROR_STOP=1 -q "$@"; }
sql() { quiet_psql "$1" -At -c "$2"; }
sql "$admin" "SELECT 1" >/dev/null || die "cannot reach Postgres at $admin (set VINT_TEST_POSTGRES_URL)"

if ((smoke)); then
  out_dir=$(mktemp -d "${TMPDIR:-/tmp}/vint-queue-smoke.XXXXXX")
  trap 'rm -rf "$out_dir"' EXIT
else
  out_dir=$repo/target/queue-bench
fi
mkdir -p "$out_dir"
results=$out_dir/$(date -u +%Y%m%dT%H%M%SZ).jsonl

commit=$(git -C "$repo" rev-parse --short HEAD)
git -C "$repo" diff --quiet HEAD -- . || commit="$commit+dirty"
env_json=$(jq -cn \
  --arg commit "$commit" --arg rustc "$(rustc --version)" \
  --arg postgres "$(sql "$admin" "SHOW server_version")" \
  --arg synchronous_commit "$(sql "$admin" "SHOW synchronous_commit")" --arg sslmode "$PGSSLMODE" \
  --arg loadavg "$(cut -d' ' -f1-3 /proc/loadavg)" --arg cores "$(nproc)" \
  --argjson rounds "$rounds" --argjson ceiling_s "$ceiling_s" --argjson awa_jobs "$awa_jobs" \
  '{bench: "queue_env", commit: $commit, rustc: $rustc, postgres: $postgres,
    synchronous_commit: $synchronous_commit, sslmode: $sslmode, loadavg_start: $loadavg, cores: ($cores | tonumber),
    rounds: $rounds, ceiling_s: $ceiling_s, awa_jobs: $awa_jobs}')
echo "$env_json" | tee -a "$results"

# --- Build everything first, so no build lands inside a timed round.
echo "building the coordinator bench (profile $bench_profile) ..."
(cd "$repo" && cargo bench -q --profile "$bench_profile" -p vint-tests --bench coordinator --no-run)

build_awa() {
  echo "building awa-bench from a copy under target/peers/awa-bench ..."
  local awa_src=$repo/target/peers/awa-bench
  mkdir -p "$awa_src"
  rm -rf "$awa_src/src"
  cp -a "$peers/awa-bench/Cargo.toml" "$peers/awa-bench/src" "$awa_src/"
  [[ -f $peers/awa-bench/Cargo.lock ]] && cp -a "$peers/awa-bench/Cargo.lock" "$awa_src/"
  # Inside this repository's tree cargo would take the copy for a stray member of vint's workspace:
  # an empty [workspace] table makes the copy a workspace of its own.
  printf '\n[workspace]\n' >>"$awa_src/Cargo.toml"
  (cd "$awa_src" && CARGO_TARGET_DIR="$awa_src/target" cargo build -q --release)
  awabench=$awa_src/target/release/awabench
}
# Not in an `||` list: errexit would be off inside the function.
if ((!smoke)); then build_awa; fi

# --- One run of each kind; each appends one JSON line to $results and prints a line.

run_ceiling() { # round
  local url rows
  url=$(db_url "$ceiling_db")
  rows=$((ceiling_s * ceiling_rows_per_s))
  sql "$admin" "DROP DATABASE IF EXISTS $ceiling_db WITH (FORCE)"
  sql "$admin" "CREATE DATABASE $ceiling_db"
  quiet_psql "$url" -f "$peers/pg-ceiling/schema.sql" >/dev/null
  quiet_psql "$url" -v nrows="$rows" -f "$peers/pg-ceiling/load_n.sql" >/dev/null
  local log tps done_rows stages_left
  log=$(pgbench -n -M prepared -c 2 -j 2 -T "$ceiling_s" -f "$peers/pg-ceiling/lease_batch64.pgb" "$url" 2>&1) ||
    { echo "$log" >&2; die "pgbench failed"; }
  tps=$(sed -n 's/^tps = \([0-9.]*\) .*/\1/p' <<<"$log" | head -1)
  [[ -n $tps ]] || { echo "$log" >&2; die "no 'tps = ' line in pgbench's output"; }
  done_rows=$(sql "$url" "SELECT count(*) FROM tasks WHERE state = 2")
  # Every transaction picks one of 4 stages; one that ran dry would lease fewer than 64 and the
  # tps x 64 figure would overstate the ceiling.
  stages_left=$(sql "$url" "SELECT count(DISTINCT stage) FROM tasks WHERE state = 0")
  ((stages_left == 4)) || die "the ceiling's queue ran dry in $ceiling_s s ($rows rows, $done_rows done): raise ceiling_rows_per_s in benches/queue.sh"
  sql "$admin" "DROP DATABASE $ceiling_db WITH (FORCE)"
  jq -cn --argjson round "$1" --argjson tps "$tps" --argjson batch "$ceiling_batch" \
    --argjson done_rows "$done_rows" --argjson seconds "$ceiling_s" --argjson rows "$rows" \
    '{bench: "queue_run", case: "ceiling/pgbench-batch64", kind: "ceiling", backend: "postgres", batch: $batch,
      round: $round, tasks_per_s: ($tps * $batch | round), tps: $tps, seconds: $seconds, rows_loaded: $rows,
      rows_completed: $done_rows, rows_completed_per_s: ($done_rows / $seconds | round)}' | tee -a "$results"
}

run_coordinator() { # round, filters...
  local round=$1 log
  shift
  log=$(cd "$repo" && VINT_BENCH_REPEATS=1 cargo bench -q --profile "$bench_profile" -p vint-tests --bench coordinator -- "$@" 2>&1) ||
    { echo "$log" >&2; die "the coordinator bench failed"; }
  grep '^  ' <<<"$log" || true
  grep '"bench":"coordinator_lease_complete"' <<<"$log" |
    jq -c --argjson round "$round" \
      '{bench: "queue_run", case: ("coordinator/" + .case), kind: "coordinator", backend, batch, round,
        tasks_per_s: .median_tasks_per_s, tasks, workers, prefetch, profile, elapsed_s: .runs_elapsed_s[0],
        p50_lease_rpc_ms, p50_complete_rpc_ms}' >>"$results"
}

run_awa() { # round
  local line
  line=$("$awabench" process --admin-url "$admin" --db "$awa_db" --jobs "$awa_jobs" --workers "$awa_workers" \
    --tag "queue-round$1" 2>/dev/null | tail -1) || die "awabench process failed (run it by hand: $awabench process --admin-url $admin --db $awa_db --jobs $awa_jobs --workers $awa_workers)"
  jq -c --argjson round "$1" --argjson workers "$awa_workers" \
    '{bench: "queue_run", case: "awa/process-w\($workers)", kind: "awa", backend: "postgres",
      batch: null, workers: $workers, round: $round, tasks_per_s: (.jobs_per_s | round), jobs: .jobs, elapsed_s: .elapsed_s,
      sync: .sync, awa_version: .awa_version}' <<<"$line" | tee -a "$results"
}

for ((round = 1; round <= rounds; round++)); do
  echo "round $round of $rounds (load average $(cut -d' ' -f1-3 /proc/loadavg))"
  if ((!smoke)); then run_ceiling "$round"; fi
  run_coordinator "$round" "$@"
  if ((!smoke)); then run_awa "$round"; fi
done
if ((!smoke)); then sql "$admin" "DROP DATABASE IF EXISTS $awa_db WITH (FORCE)"; fi
echo "load average at end: $(cut -d' ' -f1-3 /proc/loadavg)"

# --- Summary: per case over the rounds; ratios of medians.
summary=$(jq -cs --argjson env "$env_json" --arg loadavg_end "$(cut -d' ' -f1-3 /proc/loadavg)" '
  def median: sort | if length % 2 == 1 then .[length / 2 | floor] else (.[length / 2 - 1] + .[length / 2]) / 2 end;
  [.[] | select(.bench == "queue_run")] | group_by(.case) | map(
    (map(.tasks_per_s)) as $r
    | .[0] + {bench: "queue", runs_tasks_per_s: $r, median_tasks_per_s: ($r | median | round),
              min_tasks_per_s: ($r | min), max_tasks_per_s: ($r | max), rounds: ($r | length),
              commit: $env.commit, postgres: $env.postgres, synchronous_commit: $env.synchronous_commit,
              loadavg_start: $env.loadavg_start, loadavg_end: $loadavg_end}
    | del(.round, .tasks_per_s, .tps, .elapsed_s, .rows_completed, .rows_completed_per_s, .jobs))
  | sort_by(.kind != "ceiling", .kind != "coordinator", .kind != "awa", .backend, .batch)' "$results")

echo
printf '%-34s %12s %10s %10s\n' case median/s min/s max/s
jq -r '.[] | [.case, .median_tasks_per_s, .min_tasks_per_s, .max_tasks_per_s] | @tsv' <<<"$summary" |
  while IFS=$'\t' read -r case med lo hi; do printf '%-34s %12.0f %10.0f %10.0f\n' "$case" "$med" "$lo" "$hi"; done

echo
jq -r '
  (map(select(.kind == "ceiling"))[0].median_tasks_per_s) as $ceiling
  | (map(select(.kind == "awa"))[0].median_tasks_per_s) as $awa
  | .[] | select(.kind == "coordinator" and .backend == "postgres")
  | "\(.case): / ceiling = \(if $ceiling then (.median_tasks_per_s / $ceiling * 100 | round | tostring) + " %" else "n/a" end), / awa = \(if $awa then ((.median_tasks_per_s / $awa * 100 | round) / 100 | tostring) + "x" else "n/a" end)"' <<<"$summary"

echo
echo "$env_json"
jq -c '.[]' <<<"$summary" | tee -a "$results"
if ((!smoke)); then echo "every run: $results"; fi
