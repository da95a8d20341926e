# tests/integ/lib/hosts.sh - several slimfarmd hosts in one test (farmd_hosts*.sh):
# each host's pid and API URL by name, and the calls to them.  Sourced after
# lib/farm.sh (daemon_start, fail, $tmp) and lib/pg.sh; $URL is the store's.
#
#   hosts_store [ARG...] the test's PostgreSQL (pg_start ARG...; the test SKIPs, exit 0, without
#                       one), hosts_cleanup as the EXIT trap, a new store at $URL and the
#                       printer and material profiles in $tmp
#   host_farm_ini NAME LEASE_S [STORE_URL]
#                       the [farm] section of host NAME's ini on stdout: a lease of LEASE_S,
#                       the store STORE_URL (default $URL)
#   start_host NAME     slimfarmd on $tmp/NAME.ini, logging to $tmp/NAME.log
#   on HOST CMD...      run CMD against HOST's API
#   psql_q SQL          one query on the store, unaligned
#   hosts_cleanup       kill -9 every host (resumed first, if stopped), the test's
#                       own cleanup, the server: the EXIT trap
declare -A hpid hurl
hosts_store() {
  pg_start "$@" > "$tmp/pg.out" 2>&1 || {
    cat "$tmp/pg.out"
    echo "$(basename "$0" .sh): SKIP (no PostgreSQL)"
    exit 0
  }
  trap hosts_cleanup EXIT
  URL=$(pg_url postgres)
  "$D" --init-store "$URL" > /dev/null || fail "--init-store $URL"
  cp -r config/printers config/materials "$tmp/"
}
host_farm_ini() {
  printf '[farm]\nlisten: 127.0.0.1:0\ndata_dir: %s/data/%s\napi_keys: %s\nprofiles_dir: %s\n' \
    "$tmp" "$1" "$RW" "$tmp"
  printf 'store: %s\nhost: %s\nhost_lease_s: %s\n' "${3:-$URL}" "$1" "$2"
}
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
