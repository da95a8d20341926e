#!/usr/bin/env bash
# store_pg: the store on PostgreSQL.  A server of the test's own
# (lib/pg.sh: a temp dir, a Unix socket, removed at exit) runs the unit
# tests that open a store with SLIMFARM_TEST_STORE set, each data dir in a
# fresh database (tests/tstore.h), so the store, farm and API cases run on
# both engines (the suite runs them on SQLite); test_farm_host also cuts a
# host's connection through a loopback proxy.  Then slimfarmd
# --init-store creates, finds up to date and refuses a newer schema on
# PostgreSQL, and never prints a URL's password.
. "$(dirname "$0")/lib/pg.sh"
set -u
: "${BUILD:=build/san}"
TMP=$(mktemp -d)
# a throw-away server (its disk flushes prove nothing here), with a loopback port besides its
# socket: test_farm_host cuts a host's network there (tests/tools/tcpproxy)
PG_TCP=1 pg_start fsync=off || exit 1
trap 'pg_stop; rm -rf "$TMP"' EXIT
fail=0
# The programs run side by side (STORE_PG_JOBS, default 4): each runs its cases in databases
# of its own (tstore.h), and they mostly wait (leases run out, locks time out): one after the
# other they took 195 s of wall for 17 s of CPU.  The longest first.
progs="test_farm_lease test_farm test_farm_host test_storeq test_api test_sqldb test_store test_store_file test_store_query test_store_host test_store_command test_farm_view test_notify test_history test_metrics test_web"
running=0
for t in $progs; do
  SLIMFARM_TEST_STORE=$PG_URL SLIMFARM_TEST_PG_PORT=$PG_PORT \
    SLIMFARM_TEST_PROXY=$BUILD/tests/tools/tcpproxy "$BUILD/tests/$t" > "$TMP/$t.log" 2>&1 &
  running=$((running + 1))
  if [ "$running" -ge "${STORE_PG_JOBS:-4}" ]; then
    wait -n
    running=$((running - 1))
  fi
done
wait
for t in $progs; do
  last=$(tail -n 1 "$TMP/$t.log")
  echo "   $t on PostgreSQL: $last"
  if ! [[ "$last" =~ ^[0-9]+\ passed,\ 0\ failed ]]; then
    grep -v '^ok ' "$TMP/$t.log" | tail -n 30
    fail=1
  fi
done
# the cases that need SQLite's file are the only ones skipped
skipped=$(grep -c '^skip ' "$TMP/test_store.log")
[ "$skipped" -le 4 ] || { echo "test_store skipped $skipped cases on PostgreSQL"; fail=1; }

D=$BUILD/bin/slimfarmd
psql -q "$PG_URL" -c 'CREATE DATABASE farm' || exit 1
url=$(pg_url farm)
out=$("$D" --init-store "$url") || { echo "--init-store: $out"; exit 1; }
[ "$out" = "store created at schema $(psql -qtA "$url" -c 'SELECT version FROM schema_version')" ] ||
  { echo "--init-store said: $out"; exit 1; }
out=$("$D" --init-store "$url") && [[ "$out" == *"up to date"* ]] || { echo "again: $out"; exit 1; }
psql -q "$url" -c 'UPDATE schema_version SET version = version + 1' || exit 1
"$D" --init-store "$url" > "$TMP/out" 2>&1 && { echo "a newer schema was accepted"; exit 1; }
grep -q "is newer than this slimfarm" "$TMP/out" || { cat "$TMP/out"; exit 1; }
psql -q "$url" -c 'UPDATE schema_version SET version = version - 1' || exit 1
# --fsck of a shared store: its checks, and no recovery (each host recovers its own work
# when it joins): a printing job stays printing, a broken one is named
printf '[farm]\ndata_dir: %s/data\nstore: %s\n' "$TMP" "$url" > "$TMP/farm.ini"
out=$("$D" -c "$TMP/farm.ini" --fsck 2>&1) && [[ "$out" == "store "*": ok, 0 jobs, not recovered"* ]] ||
  { echo "--fsck of an empty shared store: $out"; exit 1; }
sha=$(printf x | sha256sum | cut -c1-64)
job() { # STATE PRINTER: a job in STATE on PRINTER with its open print
  psql -qtA "$url" -c "WITH j AS (INSERT INTO jobs(name, file_sha, gcode_sha, state, method,
    deviation_mm, overhang_deg, copies, max_retries, material, target_printer, target_group,
    priority, printer, created_ms, updated_ms) VALUES('p.stl', '$sha', '$sha', '$1', 'none', 0, 45,
    1, 2, 'PLA', '', '', 0, '$2', 1, 1) RETURNING id) INSERT INTO prints(job_id, copy, printer,
    material, start_line, lines_acked, started_ms, ended_ms, outcome)
    SELECT id, 1, '$2', 'PLA', 1, 0, 1, 0, '' FROM j RETURNING job_id"
}
psql -q "$url" -c "INSERT INTO files(sha256, size, created_ms) VALUES('$sha', 1, 1)" || exit 1
id=$(job printing mk3) || exit 1
out=$("$D" -c "$TMP/farm.ini" --fsck 2>&1) && [[ "$out" == *": ok, 1 jobs, not recovered"* ]] ||
  { echo "--fsck of a shared store with a print: $out"; exit 1; }
[ "$(psql -qtA "$url" -c "SELECT state FROM jobs WHERE id = $id")" = printing ] ||
  { echo "--fsck recovered a shared store's print"; exit 1; }
id=$(job printing '') || exit 1
out=$("$D" -c "$TMP/farm.ini" --fsck 2>&1) && { echo "--fsck passed a broken store: $out"; exit 1; }
[[ "$out" == *"job on a printer without printer name: job $id"* ]] || { echo "--fsck: $out"; exit 1; }
[[ "$out" == *"farm?host="* ]] || { echo "--fsck does not name the store: $out"; exit 1; }
"$D" --init-store "postgresql://nobody:hunter2@/farm?host=$PG_DIR" > "$TMP/out" 2>&1 &&
  { echo "an unknown role connected"; exit 1; }
grep -q "nobody:\*\*\*@" "$TMP/out" && ! grep -q hunter2 "$TMP/out" || { cat "$TMP/out"; exit 1; }
"$D" --init-store "postgresql:///farm?host=$PG_DIR&user=nobody&password=hunter3" > "$TMP/out" 2>&1 &&
  { echo "an unknown role connected"; exit 1; }
grep -q "password=\*" "$TMP/out" && ! grep -q hunter3 "$TMP/out" || { cat "$TMP/out"; exit 1; }
exit $fail
