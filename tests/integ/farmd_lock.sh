#!/usr/bin/env bash
# tests/integ/farmd_lock.sh - one slimfarmd per data dir (issue 16): with a
# daemon running, a second daemon and `slimfarmd --fsck` on the same data
# dir refuse, naming the dir and the running daemon's pid, and touch
# nothing (--fsck used to run crash recovery on the live database); once
# the daemon stops, --fsck runs (on a PostgreSQL store: checks, make check-pg).
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"

cat > "$tmp/farm.ini" <<INI
[farm]
listen: 127.0.0.1:$port
data_dir: $tmp/data
api_keys: $RW
[printer mk3]
driver: marlin
port: pty:/dev/null
INI
start_daemon

want="data dir '$tmp/data' is in use by another process (pid $pid)"
out=$("$D" -c "$tmp/farm.ini" 2>&1) && fail "a second daemon started"
[[ "$out" == *"$want"* ]] || fail "second daemon message: $out"
out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) && fail "--fsck ran beside a live daemon"
[[ "$out" == *"$want"* ]] || fail "--fsck message: $out"
"$C" jobs >/dev/null || fail "the live daemon stopped answering"

kill -TERM $pid; wait $pid; rc=$?; pid=
[ $rc -eq 0 ] || fail "SIGTERM exit status $rc"
out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) || fail "--fsck after the stop: $out"
store=$tmp/data # the store it names: SQLite's data dir, or the test's PostgreSQL database
[ -n "${SLIMFARM_TEST_STORE:-}" ] && store=$(daemon_db "$tmp/farm.ini")
[[ "$out" == *"store $store: ok"* ]] || fail "--fsck output: $out"
echo "farmd_lock: ok"
