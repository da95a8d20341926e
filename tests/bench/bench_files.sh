#!/usr/bin/env bash
# bench_files.sh BUILD - the cost of sharing a file through a PostgreSQL
# store (store_blob.c) against the data dir alone (SQLite, one host), at
# BENCH_FILES_MB MiB (default 100), for G-code text (which PostgreSQL's
# TOAST compresses) and for random bytes (as a 3MF's deflated parts): the
# store's writer (hash, write, fsync, and on PostgreSQL the upload), adopt
# then record (a slice's output), a fetch into another host's empty cache,
# the database size each adds, and each step's peak RSS (/usr/bin/time -v,
# a process per step).  The server is the bench's own on a Unix socket
# (lib/pg.sh) with its default durability.  Wall times on a shared
# machine: give the load next to them.
set -u
build=${1:-build/rel}
mb=${BENCH_FILES_MB:-100}
B=$build/bench/bench_files
[ -x "$B" ] || { echo "bench_files: $build not built"; exit 1; }
[ -x /usr/bin/time ] || { echo "bench_files: /usr/bin/time missing (Debian package time)"; exit 0; }
. "$(dirname "$0")/../integ/lib/pg.sh"
work=$(mktemp -d)
pg_start || exit 1
trap 'pg_stop; rm -rf "$work"' EXIT
echo "$mb MiB files; $(uptime | sed 's/.*load/load/')"

# run STEP ARGS...: the step's line with its peak RSS
run() {
  local out
  out=$(/usr/bin/time -f '%M' -o "$work/rss" "$B" "$@") || { echo "  $1 failed"; return 1; }
  echo "  $out; peak RSS $(($(tail -n 1 "$work/rss") / 1024)) MiB"
  sha=${out##* }
}

dbsize() {
  psql -qtA "$(pg_url "$1")" -c "SELECT pg_database_size(current_database())"
}

for kind in gcode random; do
  echo "$kind:"
  "$B" make "$work/src" "$mb" "$kind" || exit 1
  mkdir -p "$work/$kind-copy"
  t0=$(date +%s%N)
  cp "$work/src" "$work/$kind-copy/f" && sync "$work/$kind-copy/f"
  echo "  cp + sync (a plain copy in the page cache, for scale): $((($(date +%s%N) - t0) / 1000000)) ms"
  echo " SQLite (the data dir is the store):"
  run put "$work/$kind-lite" "$work/src"
  for step in put adopt; do
    psql -q "$PG_URL" -c "CREATE DATABASE ${kind}_$step" || exit 1
    "$B" fetch "$work/$kind-init-$step" 0 "$(pg_url "${kind}_$step")" > /dev/null 2>&1 # migrate
    before=$(dbsize "${kind}_$step")
    echo " PostgreSQL, $step:"
    if [ "$step" = adopt ]; then
      mkdir -p "$work/$kind-pg-$step/files" && cp "$work/src" "$work/$kind-pg-$step/files/made"
      run adopt "$work/$kind-pg-$step" "$work/$kind-pg-$step/files/made" "$(pg_url "${kind}_$step")"
    else
      run put "$work/$kind-pg-$step" "$work/src" "$(pg_url "${kind}_$step")"
    fi
    echo "  database grew $((($(dbsize "${kind}_$step") - before) / 1048576)) MiB"
  done
  echo " PostgreSQL, fetch into another host's empty cache:"
  run fetch "$work/$kind-pg-b" "$sha" "$(pg_url "${kind}_put")"
  rm -rf "$work/src" "$work/$kind"-*
done
