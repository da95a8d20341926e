# tests/integ/lib/pg.sh - a PostgreSQL server of the test's own: initdb and
# pg_ctl into a temporary dir, listening on a Unix socket in that dir only
# (listen_addresses empty: no TCP port to clash with a neighbour or a
# system server), trust authentication for the dir's user postgres.  The
# server binaries run as Debian's postgres user when the test runs as root
# (initdb refuses root).  Sourced, not run.
#
#   pg_start [OPTION=VALUE ...]   start it (extra postgres -c settings); sets
#                                 PG_DIR and PG_URL (its postgres database)
#   PG_TCP=1 pg_start ...         also listen on 127.0.0.1, on a free port the
#                                 kernel picked (PG_PORT): for tests that cut
#                                 the network (tests/tools/tcpproxy)
#   pg_url DB                     the URL of database DB on it (Unix socket)
#   pg_tcp_url DB [PORT]          the same over TCP (PORT: a proxy's; default PG_PORT)
#   pg_ctl_as ARGS...             pg_ctl on its data dir as its owner (stop, start)
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
  if ! pg_as "$bin/initdb" -D "$PG_DIR/data" -U postgres --auth=trust -E UTF8 --no-sync \
    > "$PG_DIR/initdb.log" 2>&1; then
    echo "pg.sh: initdb failed:"; tail -n 5 "$PG_DIR/initdb.log"; return 1
  fi
  # a free port can be taken between the probe and the server's bind: try three
  local try
  for try in 1 2 3; do
    PG_PORT=
    opts=()
    if [ -n "${PG_TCP:-}" ]; then
      PG_PORT=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
      opts=(-c listen_addresses=127.0.0.1 -c "port=$PG_PORT")
    else
      opts=(-c listen_addresses=)
    fi
    for o in "unix_socket_directories=$PG_DIR" "$@"; do opts+=(-c "$o"); done
    # pg_ctl -w waits until the server accepts connections (60 s on a loaded machine)
    pg_as "$bin/pg_ctl" -D "$PG_DIR/data" -l "$PG_DIR/server.log" -w -t 60 \
      -o "${opts[*]@Q}" start > /dev/null && break
    if [ -z "$PG_PORT" ] || [ "$try" = 3 ]; then
      echo "pg.sh: the server did not start:"; tail -n 5 "$PG_DIR/server.log"; return 1
    fi
  done
  PG_URL=$(pg_url postgres)
}

pg_url() {
  echo "postgresql:///$1?host=$PG_DIR&user=postgres${PG_PORT:+&port=$PG_PORT}"
}

pg_tcp_url() {
  echo "postgresql://postgres@127.0.0.1:${2:-$PG_PORT}/$1"
}

# pg_ctl_as stop -m fast / pg_ctl_as start: the same server, same settings (pg_ctl keeps
# the last start's options in postmaster.opts).
pg_ctl_as() {
  local cmd=$1
  shift
  if [ "$cmd" = start ]; then
    pg_as "$(pg_bindir)/pg_ctl" -D "$PG_DIR/data" -l "$PG_DIR/server.log" -w -t 60 \
      -o "$(pg_opts)" start "$@"
  else
    pg_as "$(pg_bindir)/pg_ctl" -D "$PG_DIR/data" -w -t 60 "$cmd" "$@"
  fi
}

# The options the server last started with (postmaster.opts, after the binary).
pg_opts() {
  sed -e 's/^[^ ]* //' "$PG_DIR/data/postmaster.opts"
}

pg_stop() {
  [ -n "${PG_DIR:-}" ] && [ -d "$PG_DIR" ] || return 0
  [ -f "$PG_DIR/data/postmaster.pid" ] &&
    pg_as "$(pg_bindir)/pg_ctl" -D "$PG_DIR/data" -m immediate -w -t 60 stop > /dev/null 2>&1
  rm -rf "$PG_DIR"
  PG_DIR=
}
