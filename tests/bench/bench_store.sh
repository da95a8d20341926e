#!/usr/bin/env bash
# bench_store.sh BUILD - the store's cost per call on SQLite and on
# PostgreSQL side by side (bench_store.c): N jobs added and moved, each a
# durable transaction with its event, then the loop's and the API's reads.
# PostgreSQL is a server of the bench's own on a Unix socket (lib/pg.sh),
# with its default durability (fsync, synchronous_commit on), in the same
# file system as SQLite's file.  N defaults to 10,000 (BENCH_STORE_N).
set -u
build=${1:-build/rel}
n=${BENCH_STORE_N:-10000}
[ -x "$build/bench/bench_store" ] || { echo "bench_store: $build not built"; exit 1; }
. "$(dirname "$0")/../integ/lib/pg.sh"
work=$(mktemp -d)
pg_start || exit 1
trap 'pg_stop; rm -rf "$work"' EXIT
psql -q "$PG_URL" -c 'CREATE DATABASE bench' || exit 1
echo "$n jobs; $(uptime | sed 's/.*load/load/')"
"$build/bench/bench_store" "$work/lite" "$n"
"$build/bench/bench_store" "$work/pg" "$n" "$(pg_url bench)"
