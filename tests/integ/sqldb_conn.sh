#!/usr/bin/env bash
# sqldb_conn: sqldb's PostgreSQL connection when the server or the network
# goes away (tests/unit/test_sqldb_conn.c): the server stopped for 30 s
# under a writer, a loopback proxy (tests/tools/tcpproxy) cutting a
# transaction and a LISTEN, a silent network bounded by connect_timeout
# with the session restored after it, the store re-taking its lock.  A server of the
# test's own (lib/pg.sh) with a loopback port besides its Unix socket.
# Skips (passes, saying so) when the PostgreSQL server is not installed;
# `make check` installs it (make deps).
. "$(dirname "$0")/lib/pg.sh"
set -u
: "${BUILD:=build/san}"
if [ ! -x "$(pg_bindir)/initdb" ]; then
  echo "   skipped: no PostgreSQL server installed (Debian package postgresql: make deps)"
  exit 0
fi
TMP=$(mktemp -d)
PG_TCP=1 pg_start fsync=off || exit 1 # a throw-away server: its disk flushes prove nothing here
trap 'pg_stop; rm -rf "$TMP"' EXIT
psql -q "$PG_URL" -c 'CREATE DATABASE conn' || exit 1
# the server's stop and start for the test program, as this shell does them
cat > "$TMP/pgctl" <<EOT
#!/usr/bin/env bash
. "$(cd "$(dirname "$0")" && pwd)/lib/pg.sh"
PG_DIR=$PG_DIR
pg_ctl_as "\$@"
EOT
chmod +x "$TMP/pgctl"
SQLDB_CONN_URL=$(pg_url conn) SQLDB_CONN_DB=conn SQLDB_CONN_PORT=$PG_PORT \
  SQLDB_CONN_PROXY=$BUILD/tests/tools/tcpproxy SQLDB_CONN_PGCTL=$TMP/pgctl \
  "$BUILD/tests/test_sqldb_conn" > "$TMP/log" 2>&1
grep -v '^ok ' "$TMP/log"
last=$(tail -n 1 "$TMP/log")
[[ "$last" =~ ^[0-9]+\ passed,\ 0\ failed,\ 0\ skipped ]] || { echo "sqldb_conn: $last"; exit 1; }
