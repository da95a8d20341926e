#!/usr/bin/env bash
# farmd_pg: the farm's own scenarios with slimfarmd on PostgreSQL (issue 32:
# the suite passes on both engines).  One server of the test's own
# (lib/pg.sh); each scenario runs unchanged with SLIMFARM_TEST_STORE set, so
# lib/daemon.sh gives each daemon's config `store:` on a database of its own
# (the daemon then runs as the one host of that store).  The scenarios:
# the API's jobs, reasons, events and reloads (farmd), the printers managed at
# run time and their jobs (farmd_printers), the network printers and a kill -9
# mid-print whose restart takes the print back once it joined (farmd_net: the
# restart waits out its predecessor's lease, 30 s).  The ones that
# read or check SQLite's file itself (farmd_crash's --fsck, farmd_lock,
# farmd_store_busy) stay SQLite's.
. "$(dirname "$0")/lib/pg.sh"
set -u
umask 077 # as tests/run.sh: the scenarios' configs hold keys
: "${BUILD:=build/san}"
export BUILD
pg_start fsync=off max_connections=200 || exit 1
trap pg_stop EXIT
export SLIMFARM_TEST_STORE=$PG_URL
fail=0
dir=$(dirname "$0")
for t in ${FARMD_PG_TESTS:-farmd farmd_printers farmd_net}; do # (a few, to look into one)
  t0=$SECONDS
  out=$(bash "$dir/$t.sh" 2>&1)
  rc=$?
  echo "   $t on PostgreSQL: rc $rc, $((SECONDS - t0)) s"
  if [ $rc -ne 0 ]; then
    echo "$out" | tail -n 40
    fail=1
  fi
done
n=$(psql -qtA "$PG_URL" -c "SELECT count(*) FROM pg_database WHERE datname LIKE 't\_%'")
[ "$n" -ge 2 ] || { echo "only $n scenario databases: the daemons did not run on PostgreSQL"; fail=1; }
[ $fail = 0 ] && echo "farmd_pg: ok"
exit $fail
