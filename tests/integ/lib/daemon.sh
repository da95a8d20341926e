# tests/integ/lib/daemon.sh - start slimfarmd on a port the kernel picks
# (its config says listen: 127.0.0.1:0) and learn the port from the
# daemon's "listening on ADDRESS:PORT" log line.  A port chosen by the test
# (random, or bound and released by a helper) can be taken by another
# process before the daemon binds it; the kernel's choice cannot.  Sourced,
# not run; needs $D.

# daemon_start CONFIG LOG: start "$D" -c CONFIG, appending to LOG; once its
# "listening on" line is there, set $pid and $http_port and export
# SLIMFARM_URL.  Returns 1 when the daemon exits or says nothing for 60 s.
# On the test's PostgreSQL (daemon_store) it also waits until the daemon
# joined as its store's host, as an SQLite daemon is at once: a restart after
# kill -9 waits out its predecessor's lease first, and only then takes back
# its prints and claims jobs (a scenario written for SQLite checks that
# right after the start).  It exports DAEMON_HOST, the host name it joined
# as ("" on SQLite): a store host's /metrics labels its printers' series
# host="NAME" (stable as other hosts join or leave), a single host's not.
daemon_start() {
  local cfg=$1 log=$2 from line end=$((SECONDS + 60)) joined=
  export DAEMON_HOST=
  daemon_store "$cfg" || return 1
  grep -q '^store: postgresql://[^?]*/t_[0-9a-f]\{16\}' "$cfg" && joined=1
  touch "$log"
  from=$(($(stat -c %s "$log") + 1))
  "$D" -c "$cfg" >> "$log" 2>&1 &
  pid=$!
  while [ $SECONDS -lt $end ]; do
    line=$(tail -c +"$from" "$log" | grep -m 1 -o 'slimfarmd: listening on [^ ]*:[0-9]*,')
    if [ -n "$line" ]; then
      line=${line%,}
      http_port=${line##*:}
      export SLIMFARM_URL=http://127.0.0.1:$http_port
      [ -z "$joined" ] && return 0
      end=$((SECONDS + DAEMON_LEASE_S + 120))
      while [ $SECONDS -lt $end ]; do
        line=$(tail -c +"$from" "$log" | grep -m 1 -o '^[^ ]* info host: [^ ]* joined (token')
        if [ -n "$line" ]; then
          line=${line#* info host: }
          DAEMON_HOST=${line% joined (token}
          return 0
        fi
        kill -0 "$pid" 2> /dev/null || return 1
        sleep 0.1
      done
      return 1
    fi
    kill -0 "$pid" 2> /dev/null || return 1
    sleep 0.05
  done
  return 1
}

# The lease daemon_store gives a daemon on the test's PostgreSQL: its restart after
# kill -9 waits this out (the default, 30 s, would make the crash scenarios' ten
# kills take minutes).  One host: nothing else reaps it when a loaded machine delays
# a heartbeat.
DAEMON_LEASE_S=10

# daemon_store CONFIG: with SLIMFARM_TEST_STORE (a PostgreSQL server's URL,
# tests/integ/farmd_pg.sh), the config's [farm] gains `store:` on a database of
# its own, named for the config's path (a restarted daemon finds its jobs
# again), created once, and a lease of DAEMON_LEASE_S; a config that names a
# store keeps it.  Without it,
# nothing: the daemon's SQLite in its data dir.
daemon_store() {
  local cfg=$1 db url
  [ -n "${SLIMFARM_TEST_STORE:-}" ] || return 0
  grep -q '^store:' "$cfg" && return 0
  db=t_$(realpath "$cfg" | md5sum | cut -c1-16)
  if ! psql -qtA "$SLIMFARM_TEST_STORE" -c "SELECT 1 FROM pg_database WHERE datname = '$db'" | grep -q 1; then
    psql -q "$SLIMFARM_TEST_STORE" -c "CREATE DATABASE $db" || return 1
  fi
  url=$(echo "$SLIMFARM_TEST_STORE" | sed "s|^\(postgresql://[^/]*/\)[^?]*|\1$db|")
  awk -v line="store: $url" -v lease="host_lease_s: $DAEMON_LEASE_S" \
    '{ print } !done && /^\[farm\]/ { print line; print lease; done = 1 }' "$cfg" > "$cfg.store" &&
    cat "$cfg.store" > "$cfg" && rm -f "$cfg.store" # (cat: the config keeps its mode)
}

# daemon_db CONFIG: the database of CONFIG's daemon, for a test that reads or writes it
# straight (a stopped daemon's): its store: URL, or else SQLite's file in its data_dir.
daemon_db() {
  local url dir
  url=$(sed -n 's/^store: *//p' "$1" | head -n 1)
  [ -n "$url" ] && { echo "$url"; return; }
  dir=$(sed -n 's/^data_dir: *//p' "$1" | head -n 1)
  echo "$dir/slimfarm.db"
}
