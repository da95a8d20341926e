# tests/integ/lib/hosts.sh - several slimfarmd hosts in one test (farmd_hosts*.sh):
# each host's pid and API URL by name, and the calls to them.  Sourced after
# lib/farm.sh (daemon_start, fail, $tmp) and lib/pg.sh; $URL is the store's.
#
#   start_host NAME     slimfarmd on $tmp/NAME.ini, logging to $tmp/NAME.log
#   on HOST CMD...      run CMD against HOST's API
#   psql_q SQL          one query on the store, unaligned
#   hosts_cleanup       kill -9 every host (resumed first, if stopped), the test's
#                       own cleanup, the server: the EXIT trap
declare -A hpid hurl
start_host() {
  daemon_start "$tmp/$1.ini" "$tmp/$1.log" || { tail -20 "$tmp/$1.log"; fail "host $1 did not come up"; }
  hpid[$1]=$pid
  hurl[$1]=$SLIMFARM_URL
  pid=
}
on() { local h=$1; shift; SLIMFARM_URL=${hurl[$h]} "$@"; }
psql_q() { psql -qAt "$URL" -c "$1"; }
hosts_cleanup() {
  for h in "${!hpid[@]}"; do kill -CONT "${hpid[$h]}" 2> /dev/null; kill -9 "${hpid[$h]}" 2> /dev/null; done
  cleanup
  pg_stop
}
