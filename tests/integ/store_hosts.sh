#!/usr/bin/env bash
# store_hosts: `slimfarm hosts` reads the hosts of a store, on SQLite (a data
# dir, opened beside its daemon) and on PostgreSQL (a server of the test's own,
# lib/pg.sh): each host with live or expired, its lease's age, pid, token, the
# jobs it holds and the printers it owns, as a table and as JSON; a store
# without hosts says so; bad arguments are usage errors.  The rows are written
# with SQL, as hosts of store_host.c write them (test_store_host covers that).
# Env: BUILD.
. "$(dirname "$0")/lib/pg.sh"
set -u
: "${BUILD:=build/san}"
bin=$(realpath "$BUILD/bin/slimfarm")
D=$(realpath "$BUILD/bin/slimfarmd")
work=$(mktemp -d)
trap 'pg_stop; rm -rf "$work"' EXIT
fails=0
fail() { echo "   FAIL: $*"; fails=$((fails + 1)); }

# the rows of two hosts: a live (lease 10 min on, beat 3 s ago) with printers m1, m2 and
# one preparing job; b expired a minute ago
now=$(($(date +%s%N) / 1000000))
rows="INSERT INTO hosts VALUES('a', 3, 4242, 11, $((now - 60000)), $((now - 3000)), $((now + 600000)), 0);
INSERT INTO hosts VALUES('b', 1, 4343, 11, $((now - 90000)), $((now - 70000)), $((now - 60000)), 0);
INSERT INTO host_printers(printer, host, since_ms) VALUES('m2', 'a', $now);
INSERT INTO host_printers(printer, host, since_ms) VALUES('m1', 'a', $now);
INSERT INTO files VALUES('$(printf '%064d' 1)', 1, $now);
INSERT INTO jobs(name, file_sha, state, method, deviation_mm, overhang_deg, copies, max_retries,
  material, target_printer, target_group, priority, created_ms, updated_ms, claimed_by)
  VALUES('p.stl', '$(printf '%064d' 1)', 'preparing', 'orient', 0, 0, 1, 1, '', '', '', 0,
  $now, $now, 'a');"

# check_store ARGS...: the hosts of the store ARGS name, both ways
check_store() {
  local out js
  out=$("$bin" hosts "$@" 2>&1) || { fail "hosts $*: $out"; return; }
  grep -qE '^HOST +STATE +LEASE AGE +PID +TOKEN +JOBS +PRINTERS$' <<<"$out" || fail "hosts $*: header: $out"
  grep -qE '^a +live +[0-9.]+ s +4242 +3 +1  m1,m2$' <<<"$out" || fail "hosts $*: host a: $out"
  grep -qE '^b +expired +[0-9.]+ s +4343 +1 +0  -$' <<<"$out" || fail "hosts $*: host b: $out"
  js=$("$bin" hosts "$@" --json) || { fail "hosts $* --json"; return; }
  python3 - "$js" <<'EOF' || fail "hosts $* --json: $js"
import json, sys
h = {x["name"]: x for x in json.loads(sys.argv[1])}
a, b = h["a"], h["b"]
assert a["state"] == "live" and b["state"] == "expired", h
assert 2.5 < a["lease_age_s"] < 600 and 69 < b["lease_age_s"] < 700, h
assert a["printers"] == ["m1", "m2"] and a["n_printers"] == 2 and b["printers"] == [], h
assert a["jobs_claimed"] == 1 and b["jobs_claimed"] == 0 and a["token"] == 3 and a["pid"] == 4242, h
EOF
}

# SQLite
"$D" --init-store "$work/data" > /dev/null || { echo "init-store failed"; exit 1; }
out=$("$bin" hosts --data "$work/data") && [ "$out" = "no hosts have joined this store" ] ||
  fail "an empty store: $out"
python3 -c 'import sqlite3, sys; c = sqlite3.connect(sys.argv[1]); c.executescript(sys.argv[2]); c.commit()' \
  "$work/data/slimfarm.db" "$rows" || { echo "sqlite rows failed"; exit 1; }
check_store --data "$work/data"

# usage errors and failures name what is wrong
out=$("$bin" hosts 2>&1); [ $? = 2 ] && [[ "$out" == "usage: slimfarm hosts "* ]] || fail "no store: $out"
out=$("$bin" hosts --store "$work/data" 2>&1); [ $? = 2 ] && [[ "$out" == *"--store wants a postgresql:// URL"* ]] ||
  fail "--store DIR: $out"
out=$("$bin" hosts --data "$work/data" --store postgresql:///x 2>&1); [ $? = 2 ] || fail "both: $out"
out=$("$bin" hosts --data "$work/none" 2>&1); [ $? = 1 ] && [[ "$out" == *"no store in data dir '$work/none'"* ]] ||
  fail "--data of no store: $out"

# PostgreSQL
pg_start fsync=off > /dev/null || exit 1
psql -q "$PG_URL" -c 'CREATE DATABASE farm' || exit 1
url=$(pg_url farm)
"$D" --init-store "$url" > /dev/null || { echo "init-store $url failed"; exit 1; }
psql -q "$url" -v ON_ERROR_STOP=1 -c "$rows" > /dev/null || { echo "pg rows failed"; exit 1; }
check_store --store "$url"

[ "$fails" -eq 0 ] && echo "   slimfarm hosts lists the hosts of an SQLite and a PostgreSQL store"
[ "$fails" -eq 0 ]
