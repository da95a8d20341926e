#!/usr/bin/env bash
# bench_sqldb.sh BUILD - sqldb's PostgreSQL connection (bench_sqldb.c):
# NOTIFY to a listener's callback over a Unix socket (median and p99 of
# N, default 1,000: BENCH_SQLDB_N), and the time from a restarted server
# accepting connections to a caller's first successful call, after
# outages of 1, 3 and 10 s, for a caller calling through the outage (its
# back-off grown) and an idle one.  A server of the bench's own (lib/pg.sh).
set -u
. "$(dirname "$0")/../integ/lib/pg.sh"
build=${1:-build/rel}
if [ ! -x "$build/bench/bench_sqldb" ]; then
  echo "bench_sqldb: $build not built"
  exit 1
fi
pg_start || exit 1
ctl=$PG_DIR/bench-pgctl # removed with the server's dir
cat > "$ctl" <<EOT
#!/usr/bin/env bash
. "$(cd "$(dirname "$0")/../integ" && pwd)/lib/pg.sh"
PG_DIR=$PG_DIR
pg_ctl_as "\$@"
EOT
chmod 755 "$ctl"
uptime | sed 's/.*load/load/'
"$build/bench/bench_sqldb" "$PG_URL" "${BENCH_SQLDB_N:-1000}" "$ctl"
