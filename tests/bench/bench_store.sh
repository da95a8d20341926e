#!/usr/bin/env bash
# bench_store.sh BUILD - the store's cost per call on SQLite and on
# PostgreSQL side by side (bench_store.c): N jobs added and moved, each a
# durable transaction with its event, then the loop's and the API's reads.
# PostgreSQL is a server of the bench's own on a Unix socket (lib/pg.sh),
# with its default durability (fsync, synchronous_commit on), in the same
# file system as SQLite's file.  N defaults to 10,000 (BENCH_STORE_N).
# Then job claims per second (bench_claims.c, issue 32's hosts): 1, 3 and 10
# claimers at once draining N queued jobs, on PostgreSQL each claimer a
# connection of its own as a host would be, on SQLite (one data dir, its
# flock: one process) each a connection of that process.
set -u
build=${1:-build/rel}
n=${BENCH_STORE_N:-10000}
for b in bench_store bench_claims; do
  [ -x "$build/bench/$b" ] || { echo "$b: $build not built"; exit 1; }
done
. "$(dirname "$0")/../integ/lib/pg.sh"
work=$(mktemp -d)
pg_start || exit 1
trap 'pg_stop; rm -rf "$work"' EXIT
psql -q "$PG_URL" -c 'CREATE DATABASE bench' || exit 1
echo "$n jobs; $(uptime | sed 's/.*load/load/')"
"$build/bench/bench_store" "$work/lite" "$n"
"$build/bench/bench_store" "$work/pg" "$n" "$(pg_url bench)"
echo "claims: $n queued jobs drained by K claimers; $(uptime | sed 's/.*load/load/')"
for k in 1 3 10; do
  psql -q "$PG_URL" -c "CREATE DATABASE claims$k" || exit 1
  "$build/bench/bench_claims" "$work/claims-pg$k" "$n" "$k" "$(pg_url claims$k)"
  "$build/bench/bench_claims" "$work/claims-lite$k" "$n" "$k"
done
