#!/usr/bin/env bash
# The paper's recipe at 2 M samples, dispatched end to end with no engine: the release coordinator
# on Postgres, timing-only workers (`vint-worker --engine-mode timing-only`: real contract results,
# outputs of the real names and sizes, constant bytes stored once in a file:// object store), the
# real planner expanding every grasp chunk into render, noise and package tasks, lineage and
# samples recorded as in a real run.
#
#   benches/dispatch.sh
#   VINT_BENCH_SMOKE=1 benches/dispatch.sh
#
# examples/vint-sim.toml (26 objects x 2 hands x 4 environments x 3 views) with its quota raised
# to 3,206 accepted grasps per (object, hand) out of at most 5,200 trials: 26 x 2 x 3,206 x 12 =
# 2,000,544 samples. Measures and writes to $OUT (target/dispatch by default):
#   plan.json        vintctl plan of the spec (what the run should write)
#   rss.csv          the coordinator's resident memory every 2 s (t_s,rss_kib)
#   progress.csv     tasks by state and samples every 10 s (t_s,queued,running,succeeded,failed,samples)
#   latency-*.csv    each worker's batches: unix_ms,slot,tasks,lease_ms,complete_ms
#   db-before.json   every table's and index's bytes and live/dead rows as the job ends
#   db-after.json    the same after VACUUM (ANALYZE)
#   lineage.json     a random sample of samples checked end to end (benches/dispatch_report.py)
#   summary.json     the figures docs/benchmarks.md quotes
#
# Settings (environment): VINT_TEST_POSTGRES_URL (admin URL, default postgres://postgres@127.0.0.1:5432/postgres),
# VINT_DISPATCH_ACCEPTED (3206), VINT_DISPATCH_TRIALS (5200), VINT_DISPATCH_WORKERS (worker processes, 2),
# VINT_DISPATCH_BATCH (tasks per lease and completion, 128), VINT_DISPATCH_CONCURRENCY (loops per worker, 2),
# VINT_DISPATCH_VERIFY (samples whose lineage is checked, 300), VINT_DISPATCH_OUT.
#
# The smoke (VINT_BENCH_SMOKE=1; seconds: the test command's check that the bench and
# benches/dispatch_report.py still run, not a figure) takes the debug binaries (scripts/test.sh has
# built them; no release build), 1 accepted grasp of 1 trial per (object, hand) (at most 624
# samples) and 5 samples' lineage, unless the settings above say otherwise; it writes to a
# temporary directory (unless VINT_DISPATCH_OUT is set; then the output stays) and to a database of
# its own, removed at exit.
set -euo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
admin=${VINT_TEST_POSTGRES_URL:-postgres://postgres@127.0.0.1:5432/postgres}
die() { echo "dispatch bench: $*" >&2; exit 2; }
smoke=${VINT_BENCH_SMOKE:-0}
[[ $smoke == 0 || $smoke == 1 ]] || die "VINT_BENCH_SMOKE = '$smoke': must be 0 or 1"
if ((smoke)); then
  accepted=${VINT_DISPATCH_ACCEPTED:-1}
  trials=${VINT_DISPATCH_TRIALS:-1}
  verify=${VINT_DISPATCH_VERIFY:-5}
  out=${VINT_DISPATCH_OUT:-}
  profile=dev
  # Named as the tests name their databases, so that scripts/test.sh drops it if this run dies
  # before its own cleanup does.
  db=vint_test_$$_dispatch_smoke
else
  accepted=${VINT_DISPATCH_ACCEPTED:-3206}
  trials=${VINT_DISPATCH_TRIALS:-5200}
  verify=${VINT_DISPATCH_VERIFY:-300}
  out=${VINT_DISPATCH_OUT:-$repo/target/dispatch}
  profile=release
  db=vint_dispatch
fi
workers=${VINT_DISPATCH_WORKERS:-2}
batch=${VINT_DISPATCH_BATCH:-128}
concurrency=${VINT_DISPATCH_CONCURRENCY:-2}

check_count() {
  [[ $2 =~ ^[0-9]+$ ]] && (($2 >= $3 && $2 <= $4)) || die "$1 = '$2': must be an integer from $3 to $4"
}
check_count VINT_DISPATCH_ACCEPTED "$accepted" 1 100000
check_count VINT_DISPATCH_TRIALS "$trials" "$accepted" 1000000
check_count VINT_DISPATCH_WORKERS "$workers" 1 64
check_count VINT_DISPATCH_BATCH "$batch" 1 256
check_count VINT_DISPATCH_CONCURRENCY "$concurrency" 1 64
check_count VINT_DISPATCH_VERIFY "$verify" 1 100000
for tool in psql python3 cargo; do
  command -v "$tool" >/dev/null || die "'$tool' is not on PATH"
done
quiet_psql() { PGOPTIONS="-c client_min_messages=warning" psql -v ON_ERROR_STOP=1 -q "$@"; }
sql() { quiet_psql "$1" -At -c "$2"; }
sql "$admin" "SELECT 1" >/dev/null || die "cannot reach Postgres at $admin (set VINT_TEST_POSTGRES_URL)"
db_url="${admin%/*}/$db"
pids=()
scratch=""
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
finish() {
  cleanup
  if ((smoke)); then
    sql "$admin" "DROP DATABASE IF EXISTS $db WITH (FORCE)" || true
    [[ -z $scratch ]] || rm -rf "$scratch"
  fi
}
trap finish EXIT

echo "== building the $profile binaries"
(cd "$repo" && cargo build --profile "$profile" --bin vint-coordinator --bin vint-worker --bin vintctl)
bin=$repo/target/$([[ $profile == dev ]] && echo debug || echo release)

if [[ -z $out ]]; then
  scratch=$(mktemp -d "${TMPDIR:-/tmp}/vint-dispatch-smoke.XXXXXX")
  out=$scratch
fi
rm -rf "$out"
mkdir -p "$out/logs"
spec=$out/spec.toml
sed -e "s/^accepted_per_pair = .*/accepted_per_pair = $accepted/" \
    -e "s/^trials_per_pair = .*/trials_per_pair = $trials/" \
    -e 's/^name = "vint_sim"/name = "vint_sim_dispatch"/' "$repo/examples/vint-sim.toml" >"$spec"
grep -q "^accepted_per_pair = $accepted\$" "$spec" || die "could not set the quota in $spec"
"$bin/vintctl" validate "$spec" >/dev/null
"$bin/vintctl" plan "$spec" --json >"$out/plan.json"
"$bin/vintctl" plan "$spec" | tee "$out/plan.txt"

sql "$admin" "DROP DATABASE IF EXISTS $db WITH (FORCE)"
sql "$admin" "CREATE DATABASE $db"

port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
url=http://127.0.0.1:$port
RUST_LOG=warn "$bin/vint-coordinator" --database "$db_url" --listen "127.0.0.1:$port" 2>"$out/logs/coordinator.log" &
coordinator=$!
pids+=("$coordinator")
for _ in $(seq 100); do
  (echo >"/dev/tcp/127.0.0.1/$port") 2>/dev/null && break
  sleep 0.1
done

start=$(date +%s.%N)
job=$("$bin/vintctl" submit "$spec" --timing-only --coordinator "$url")
submitted=$(date +%s.%N)
echo "== job $job submitted in $(python3 -c "print(f'{$submitted - $start:.1f}')") s; dispatching"

# The coordinator's resident memory, every 2 s. The samplers' stderr goes to a log: the `sleep` a
# killed sampler leaves behind must not hold the caller's stderr open after this script ends.
(
  echo "t_s,rss_kib"
  while kill -0 "$coordinator" 2>/dev/null; do
    rss=$(awk '/^VmRSS/ {print $2}' "/proc/$coordinator/status" 2>/dev/null || echo "")
    [[ -n $rss ]] && echo "$(python3 -c "import time; print(f'{time.time() - $start:.1f}')"),$rss"
    sleep 2
  done
) >"$out/rss.csv" 2>>"$out/logs/samplers.log" &
pids+=($!)
# Tasks by state and samples, every 10 s.
(
  echo "t_s,queued,running,succeeded,failed,samples"
  while kill -0 "$coordinator" 2>/dev/null; do
    row=$(sql "$db_url" "SELECT count(*) FILTER (WHERE state IN ('queued', 'blocked')), count(*) FILTER (WHERE state = 'running'), \
      count(*) FILTER (WHERE state = 'succeeded'), count(*) FILTER (WHERE state = 'failed'), (SELECT COALESCE(sum(samples), 0) FROM outputs) FROM tasks" \
      2>/dev/null | tr '|' ',' || true)
    [[ -n $row ]] && echo "$(python3 -c "import time; print(f'{time.time() - $start:.1f}')"),$row"
    sleep 10
  done
) >"$out/progress.csv" 2>>"$out/logs/samplers.log" &
pids+=($!)

store=$out/objects
for w in $(seq "$workers"); do
  RUST_LOG=warn "$bin/vint-worker" --coordinator "$url" --store "file://$store" --worker-id "timing-$w" \
    --engine-mode timing-only --batch "$batch" --concurrency "$concurrency" --latency-log "$out/latency-$w.csv" \
    2>"$out/logs/worker-$w.log" &
  pids+=($!)
done

"$bin/vintctl" watch "$job" --coordinator "$url" >"$out/logs/watch.log" 2>&1 || {
  tail -20 "$out/logs/watch.log" >&2
  die "the job did not succeed (logs in $out/logs)"
}
finished=$(date +%s.%N)
echo "== job finished: $(python3 -c "print(f'{$finished - $submitted:.1f}')") s from submit to the last sample"
cleanup
pids=()

db_state() {
  sql "$db_url" "SELECT json_build_object(
      'database_bytes', pg_database_size(current_database()),
      'samples', (SELECT COALESCE(sum(samples), 0) FROM outputs),
      'tasks', (SELECT count(*) FROM tasks),
      'tables', (SELECT json_agg(json_build_object('name', relname, 'total_bytes', pg_total_relation_size(relid),
                  'heap_bytes', pg_relation_size(relid), 'live_rows', n_live_tup, 'dead_rows', n_dead_tup) ORDER BY relname)
                 FROM pg_stat_user_tables),
      'indexes', (SELECT json_agg(json_build_object('name', indexrelname, 'table', relname,
                  'bytes', pg_relation_size(indexrelid)) ORDER BY indexrelname) FROM pg_stat_user_indexes))"
}
db_state >"$out/db-before.json"
sql "$db_url" "VACUUM (ANALYZE)"
db_state >"$out/db-after.json"

# The lineage check reads through the product's own API, so it needs the coordinator again.
RUST_LOG=warn "$bin/vint-coordinator" --database "$db_url" --listen "127.0.0.1:$port" 2>>"$out/logs/coordinator.log" &
pids+=($!)
for _ in $(seq 100); do
  (echo >"/dev/tcp/127.0.0.1/$port") 2>/dev/null && break
  sleep 0.1
done
python3 "$repo/benches/dispatch_report.py" --out "$out" --job "$job" --database "$db_url" --coordinator "$url" \
  --vintctl "$bin/vintctl" --store "$store" --verify "$verify" --submitted "$submitted" --finished "$finished" \
  --start "$start" --workers "$workers" --batch "$batch" --concurrency "$concurrency"
