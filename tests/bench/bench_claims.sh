#!/usr/bin/env bash
# bench_claims.sh BUILD - job claims per second (store_job_claim, issue 32's
# hosts) with 1, 3 and 10 claimers at once draining N queued jobs, on
# PostgreSQL and on SQLite side by side (bench_claims.c).  PostgreSQL is a
# server of the bench's own on a Unix socket (lib/pg.sh) with its default
# durability (fsync, synchronous_commit on), each claimer a connection of
# its own as a host would be; SQLite is one data dir (its flock: one
# process), each claimer a connection of that process.  N defaults to
# 10,000 (BENCH_CLAIMS_N).
set -u
build=${1:-build/rel}
n=${BENCH_CLAIMS_N:-10000}
[ -x "$build/bench/bench_claims" ] || { echo "bench_claims: $build not built"; exit 1; }
. "$(dirname "$0")/../integ/lib/pg.sh"
work=$(mktemp -d)
pg_start || exit 1
trap 'pg_stop; rm -rf "$work"' EXIT
echo "$n queued jobs, drained by K claimers; $(nproc) cores; $(uptime | sed 's/.*load/load/')"
for k in 1 3 10; do
  psql -q "$PG_URL" -c "CREATE DATABASE claims$k" || exit 1
  "$build/bench/bench_claims" "$work/pg$k" "$n" "$k" "$(pg_url claims$k)"
  "$build/bench/bench_claims" "$work/lite$k" "$n" "$k"
done
