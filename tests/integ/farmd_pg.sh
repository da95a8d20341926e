#!/usr/bin/env bash
# farmd_pg: the farm's own scenarios with slimfarmd on PostgreSQL (issue 32:
# the suite passes on both engines).  One server of the test's own
# (lib/pg.sh); each scenario runs unchanged with SLIMFARM_TEST_STORE set, so
# lib/daemon.sh gives each daemon's config `store:` on a database of its own
# (the daemon then runs as the one host of that store, and daemon_start
# waits until it joined, as an SQLite daemon is at once).
#
# In make check, three: the API's jobs, reasons, events and reloads (farmd),
# the printers managed at run time and their jobs (farmd_printers), the
# network printers and a kill -9 mid-print whose restart takes the print
# back once it joined (farmd_net: the restart waits out its predecessor's
# lease).  FARMD_PG_TESTS=all (make check-pg) runs every scenario that
# starts a daemon (tests/integ/*.sh using daemon_start or start_daemon),
# but those that start a PostgreSQL of their own (farmd_hosts*), JOBS at a
# time (default: one per core), each within FARMD_PG_TIMEOUT seconds (600);
# FARMD_PG_TESTS="a b" runs those.  A scenario that reads or writes the
# store itself does so through daemon_db (SQLite's file or the URL).
. "$(dirname "$0")/lib/pg.sh"
set -u
umask 077 # as tests/run.sh: the scenarios' configs hold keys
: "${BUILD:=build/san}"
export BUILD
dir=$(dirname "$0")
tests=${FARMD_PG_TESTS:-farmd farmd_printers farmd_net}
jobs=1
if [ "$tests" = all ]; then
  tests=
  for f in "$dir"/*.sh; do
    t=$(basename "$f" .sh)
    [ "$t" = farmd_pg ] && continue
    grep -q 'lib/pg\.sh' "$f" && continue # its own server
    grep -q 'daemon_start\|start_daemon' "$f" && tests="$tests $t"
  done
  jobs=${JOBS:-$(nproc)}
fi
pg_start fsync=off max_connections=$((100 + 100 * jobs)) || exit 1
res=$(mktemp -d)
trap 'pg_stop; rm -rf "$res"' EXIT
export SLIMFARM_TEST_STORE=$PG_URL

# one scenario into $res/NAME.out, its status and seconds into $res/NAME.rc
one() {
  local t0=$SECONDS rc
  timeout "${FARMD_PG_TIMEOUT:-600}" bash "$dir/$1.sh" > "$res/$1.out" 2>&1 < /dev/null
  rc=$?
  echo "$rc $((SECONDS - t0))" > "$res/$1.rc.part" && mv "$res/$1.rc.part" "$res/$1.rc"
}
pass=0 fail=0 failed=()
shown=" "
report() { # every scenario that ended and is not shown yet
  local t rc secs
  for t in $tests; do
    [ -f "$res/$t.rc" ] && [[ "$shown" != *" $t "* ]] || continue
    shown="$shown$t "
    read -r rc secs < "$res/$t.rc"
    echo "   $t on PostgreSQL: rc $rc, $secs s"
    if [ "$rc" = 0 ]; then
      pass=$((pass + 1))
    else
      tail -n 40 "$res/$t.out"
      fail=$((fail + 1))
      failed+=("$t")
    fi
  done
}
running=0
for t in $tests; do
  while [ "$running" -ge "$jobs" ]; do
    wait -n
    running=$((running - 1))
    report
  done
  one "$t" &
  running=$((running + 1))
done
wait
report
n=$(psql -qtA "$PG_URL" -c "SELECT count(*) FROM pg_database WHERE datname LIKE 't\_%'")
set -- $tests # a database of its own for each scenario's daemon: two of the three, one of one
want=$(($# < 2 ? $# : 2))
[ "$n" -ge "$want" ] || { echo "only $n scenario databases: the daemons did not run on PostgreSQL"; fail=$((fail + 1)); }
echo "farmd_pg: $pass scenarios passed on PostgreSQL, $fail failed${failed[*]:+: ${failed[*]}}"
[ $fail = 0 ]
