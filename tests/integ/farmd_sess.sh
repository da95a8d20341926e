#!/usr/bin/env bash
# tests/integ/farmd_sess.sh - sessions, files and logins on real daemons
# over loopback (issue 30, cases 4 and 6):
#   - the data dir 0700 and every file in it 0600 (SQLite's database, WAL,
#     SHM, lock, instance id, stored files), a loose data dir fixed at start and
#     the log says so;
#   - a farm.ini holding keys that others can read is refused, naming the
#     file and its mode; --allow-readable-config starts with a warning;
#   - two daemons with the same keys: each names its cookie after itself,
#     and neither takes the other's token under either name;
#   - --session-idle and --session-max end sessions;
#   - failed logins are logged with the address, one line per interval,
#     never the key, and an address past its burst gets 429 while a good
#     key from another address does not notice;
#   - every change is logged with its key's label; manual commands each get
#     their line with the label, repeats not folded.
set -u
umask 077 # as tests/run.sh does: the configs below hold keys
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
RO=ro-key-0123456789abcdef
others=()
main_pid=
trap 'for p in "${others[@]}"; do kill -9 "$p" 2>/dev/null; done; pid=$main_pid; cleanup' EXIT

mode() { stat -c %a "$1"; }
# code URL ARGS...: the HTTP status of a curl request
code() { local u=$1; shift; curl -s -o "$tmp/body" -w '%{http_code}' "$@" "$u"; }
# cookie URL KEY: "NAME=TOKEN" of a log in with KEY
cookie() {
  curl -s -D "$tmp/head" -o "$tmp/body" -H "X-Api-Key: $2" "$1/api/whoami" > /dev/null
  sed -n 's/^Set-Cookie: \([^;]*\);.*/\1/Ip' "$tmp/head" | tr -d '\r'
}
# with_flags NAME ARGS...: $tmp/NAME, slimfarmd with ARGS put before its own
with_flags() {
  local name=$1; shift
  printf '#!/bin/sh\nexec %s %s "$@"\n' "$D" "$*" > "$tmp/$name"
  chmod 700 "$tmp/$name"
}
# another_daemon NAME ARGS...: a printerless daemon on $tmp/NAME.ini (same
# keys) started with ARGS, its URL in $url_NAME
another_daemon() {
  local name=$1; shift
  printf '[farm]\nlisten: 127.0.0.1:0\ndata_dir: %s/%s-data\napi_keys: %s\napi_keys_readonly: %s\n' \
    "$tmp" "$name" "$RW" "$RO" > "$tmp/$name.ini"
  with_flags "$name.sh" "$@"
  D=$tmp/$name.sh daemon_start "$tmp/$name.ini" "$tmp/$name.log" ||
    { pid=$main_pid; fail "daemon $name did not start: $(tail -5 "$tmp/$name.log")"; }
  others+=($pid)
  pid=$main_pid
  eval "url_$name=http://127.0.0.1:$http_port"
}

# ---- the main daemon: a printer, and a data dir someone made loose ----
start_sim mk3 --speed 3000
cp -r config/printers config/materials "$tmp/"
mkdir -m 755 "$tmp/data"
touch "$tmp/data/notes.txt" && chmod 644 "$tmp/data/notes.txt"
printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\napi_keys_readonly: %s\n' \
  "$port" "$tmp" "$RW" "$RO" > "$tmp/farm.ini"
printf '[printer mk3]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' \
  "$(cat "$tmp/mk3.addr")" >> "$tmp/farm.ini"

# readable by others: refused, naming the file and its mode
chmod 644 "$tmp/farm.ini"
refused() { # ARGS...: slimfarmd ARGS exits 1 at once (a daemon that starts is stopped: 124)
  out=$(timeout 30 "$D" "$@" 2>&1)
  local rc=$?
  [ $rc = 1 ] || fail "slimfarmd $*: exit $rc, not refused: $out"
}
refused -c "$tmp/farm.ini"
echo "$out" | grep -q "$tmp/farm.ini.*mode 0644" || fail "refusal does not name file and mode: $out"
refused -c "$tmp/farm.ini" --check
chmod 640 "$tmp/farm.ini"
refused -c "$tmp/farm.ini"
[ "$(ls -A "$tmp/data")" = notes.txt ] || fail "a refused start touched the data dir: $(ls -A "$tmp/data")"
# ...or, with the flag, started with a loud warning
with_flags allow.sh --allow-readable-config
D0=$D D=$tmp/allow.sh
start_daemon
D=$D0
main_pid=$pid
grep -q "WARNING: $tmp/farm.ini holds API keys.*mode 0640" "$tmp/log" || fail "no warning for a readable farm.ini"
URL=$SLIMFARM_URL
wait_for 60 sh -c "'$C' printers | grep -q ' idle '" || fail "mk3 not idle: $("$C" printers)"

# ---- who changed what: the key's label, every manual command on its line ----
label="key $(printf '%s' "$RW" | python3 -c 'import sys
h = 2166136261
for c in sys.stdin.buffer.read(): h = ((h ^ c) * 16777619) & 0xffffffff
print("%08x" % h)')"
for i in 1 2 3; do
  s=$(code "$URL/api/printers/mk3/command" -H "X-Api-Key: $RW" \
    -H 'Content-Type: application/json' -d '{"command": "M117 hello"}')
  [ "$s" = 200 ] || fail "manual command $i: $s $(cat "$tmp/body")"
done
n=$(grep -c "printer\[mk3\]: manual command from $label: M117 hello" "$tmp/log")
[ "$n" = 3 ] || fail "3 manual commands, $n lines with the key's label: $(grep 'manual command' "$tmp/log")"
grep -q "repeated" "$tmp/log" && grep "manual command.*repeated" "$tmp/log" && fail "repeats folded"
grep -q "POST /api/printers/mk3/command by $label: 200" "$tmp/log" || fail "the change is not logged with its key"
# ---- modes: every file the daemon keeps is its owner's alone ----
grep -q "data dir '$tmp/data': 2 files and folders were open to other users" "$tmp/log" ||
  fail "the fixed data dir is not in the log: $(grep store "$tmp/log")"
"$C" shapes "$tmp/parts" > /dev/null
"$C" submit "$tmp/parts/tee.stl" --material PLA > /dev/null || fail "submit"
wait_for 30 sh -c "ls '$tmp/data/files/'*/* > /dev/null 2>&1" || fail "no stored file"
[ "$(mode "$tmp/data")" = 700 ] || fail "data dir is $(mode "$tmp/data")"
kept="lock instance notes.txt"
# SQLite's database and its journal (a PostgreSQL store keeps nothing here: lib/daemon.sh)
[ -n "${SLIMFARM_TEST_STORE:-}" ] || kept="slimfarm.db slimfarm.db-wal slimfarm.db-shm $kept"
for f in $kept; do
  [ -e "$tmp/data/$f" ] || fail "no $f in the data dir"
done
while read -r f; do
  m=$(mode "$f")
  if [ -d "$f" ]; then [ "$m" = 700 ] || fail "folder $f is $m"; else [ "$m" = 600 ] || fail "file $f is $m"; fi
done < <(find "$tmp/data" -mindepth 1)

# ---- a second daemon with the same keys: cookies are each daemon's own ----
another_daemon b
ca=$(cookie "$URL" "$RW")
cb=$(cookie "$url_b" "$RW")
case "$ca" in sf_session_[0-9a-f]*=[0-9a-f]*) ;; *) fail "cookie of A: '$ca'" ;; esac
[ "${ca%%=*}" = "sf_session_$(cat "$tmp/data/instance")" ] || fail "cookie $ca not named after $(cat "$tmp/data/instance")"
[ "${ca%%=*}" != "${cb%%=*}" ] || fail "two daemons name their cookies alike: ${ca%%=*}"
[ "$(code "$URL/api/jobs" -b "$ca")" = 200 ] || fail "A's cookie on A: $(cat "$tmp/body")"
[ "$(code "$url_b/api/jobs" -b "$ca")" = 401 ] || fail "A's cookie read B's jobs"
[ "$(code "$url_b/api/jobs" -b "${cb%%=*}=${ca#*=}")" = 401 ] || fail "A's token under B's name read B's jobs"
[ "$(code "$url_b/api/whoami" -b "${cb%%=*}=${ca#*=}")" = 401 ] || fail "A's token made a session on B"
[ "$(code "$url_b/api/jobs" -b "$cb")" = 200 ] || fail "B's own cookie on B"
# a restart of A keeps its name (the instance file) but knows no old token
ida=$(cat "$tmp/data/instance")
[ "$(mode "$tmp/data/instance")" = 600 ] || fail "instance file mode"

# ---- expiry, shortened for the test ----
another_daemon idle --session-idle 1
c=$(cookie "$url_idle" "$RW")
t0=$SECONDS
sleep 2.2 # only "later than the idle time" matters: a slow machine waits longer, never less
[ "$(code "$url_idle/api/jobs" -b "$c")" = 401 ] || fail "a session idle past --session-idle still reads"
another_daemon max --session-max 2 --session-idle 3600
c=$(cookie "$url_max" "$RW")
end=$((SECONDS + 60))
while [ "$(code "$url_max/api/jobs" -b "$c")" = 200 ]; do # busy, never idle
  [ $SECONDS -lt $end ] || fail "a session used all along outlived --session-max 2"
  sleep 0.2
done
grep -q "session expired" "$tmp/body" || fail "expired session: $(cat "$tmp/body")"

# ---- failed logins: logged with the address, slowed per address ----
n401=0 t0=$SECONDS
for i in $(seq 300); do # a guesser far faster than one a second meets a 429
  s=$(code "$URL/api/jobs" -H "X-Api-Key: wrong-key-$i-abcdefghijklmnop")
  [ "$s" = 429 ] && break
  [ "$s" = 401 ] || fail "wrong key $i: $s"
  n401=$((n401 + 1))
done
[ "$s" = 429 ] || fail "300 wrong keys and not one slowed (429)"
[ $n401 -ge 20 ] || fail "only $n401 wrong keys answered 401 before the first 429 (burst 20)"
for i in $(seq 30); do # hammering while refused keeps it refused
  s=$(code "$URL/api/jobs" -H "X-Api-Key: wrong-key-more-$i-abcdefghijklmnop")
  [ "$s" = 429 ] || fail "wrong key $i after the burst: $s"
done
[ "$(code "$URL/api/jobs" -H "X-Api-Key: $RW")" = 429 ] || fail "a blocked address learns a good key works"
# another address with a good key is not slowed
[ "$(code "$URL/api/jobs" --interface 127.0.0.2 -H "X-Api-Key: $RW")" = 200 ] ||
  fail "a good key from 127.0.0.2 was slowed: $(cat "$tmp/body")"
grep -q "failed login from 127.0.0.1: unknown API key" "$tmp/log" || fail "no failed login logged"
lines=$(grep -c "failed login.* from 127.0.0.1" "$tmp/log")
[ "$lines" -le $((2 + (SECONDS - t0) / 10)) ] ||
  fail "$lines log lines for $((n401 + 31)) failed logins in $((SECONDS - t0)) s"
grep -q "wrong-key" "$tmp/log" && fail "a wrong key was logged"

grep -q "$RW" "$tmp/log" "$tmp/b.log" && fail "a key is in a log"
echo "ok: sessions, files and logins (instance $ida)"
