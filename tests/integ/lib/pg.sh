# tests/integ/lib/pg.sh - a PostgreSQL server of the test's own: initdb and
# pg_ctl into a temporary dir, listening on a Unix socket in that dir only
# (listen_addresses empty: no TCP port to clash with a neighbour or a
# system server), trust authentication for the dir's user postgres.  The
# server binaries run as Debian's postgres user when the test runs as root
# (initdb refuses root).  Sourced, not run.
#
#   pg_start [OPTION=VALUE ...]   start it (extra postgres -c settings); sets
#                                 PG_DIR and PG_URL (its postgres database)
#   pg_url DB                     the URL of database DB on it
#   pg_stop                       stop it and remove PG_DIR (safe to call twice;
#                                 pg_start arranges it on EXIT, and makes TERM,
#                                 INT and HUP exit, so a killed test stops it too)

# The server's bin dir: pg_config's when it has initdb, else the newest installed.
pg_bindir() {
  local b
  b=$(pg_config --bindir 2> /dev/null)
  [ -x "$b/initdb" ] || b=$(ls -d /usr/lib/postgresql/*/bin 2> /dev/null | sort -V | tail -n 1)
  echo "$b"
}

# Run a server binary as the data dir's owner.
pg_as() {
  if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}

pg_start() {
  local bin opts=() o
  bin=$(pg_bindir)
  if [ ! -x "$bin/initdb" ]; then
    echo "pg.sh: no PostgreSQL server found (Debian package postgresql: make deps)"
    return 1
  fi
  PG_DIR=$(mktemp -d /tmp/sfpg.XXXXXX) || return 1
  trap pg_stop EXIT
  trap 'exit 143' TERM INT HUP # a killed test (run.sh's timeout) still runs its EXIT trap
  [ "$(id -u)" = 0 ] && chown postgres: "$PG_DIR"
  for o in listen_addresses= "unix_socket_directories=$PG_DIR" "$@"; do opts+=(-c "$o"); done
  if ! pg_as "$bin/initdb" -D "$PG_DIR/data" -U postgres --auth=trust -E UTF8 --no-sync \
    > "$PG_DIR/initdb.log" 2>&1; then
    echo "pg.sh: initdb failed:"; tail -n 5 "$PG_DIR/initdb.log"; return 1
  fi
  # pg_ctl -w waits until the server accepts connections (60 s on a loaded machine)
  if ! pg_as "$bin/pg_ctl" -D "$PG_DIR/data" -l "$PG_DIR/server.log" -w -t 60 \
    -o "${opts[*]@Q}" start > /dev/null; then
    echo "pg.sh: the server did not start:"; tail -n 5 "$PG_DIR/server.log"; return 1
  fi
  PG_URL=$(pg_url postgres)
}

pg_url() {
  echo "postgresql:///$1?host=$PG_DIR&user=postgres"
}

pg_stop() {
  [ -n "${PG_DIR:-}" ] && [ -d "$PG_DIR" ] || return 0
  [ -f "$PG_DIR/data/postmaster.pid" ] &&
    pg_as "$(pg_bindir)/pg_ctl" -D "$PG_DIR/data" -m immediate -w -t 60 stop > /dev/null 2>&1
  rm -rf "$PG_DIR"
  PG_DIR=
}
