#!/usr/bin/env bash
# tests/integ/farmd_lock.sh - one slimfarmd per data dir (issue 16): with a
# daemon running, a second daemon and `slimfarmd --fsck` on the same data
# dir refuse, naming the dir and the running daemon's pid, and touch
# nothing (--fsck used to run crash recovery on the live database); once
# the daemon stops, --fsck runs.
set -u
BUILD=${BUILD:-build/san}
D=$BUILD/bin/slimfarmd
C=$BUILD/bin/slimfarm
tmp=$(mktemp -d)
pid=
cleanup() { [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; echo "--- daemon log"; cat "$tmp/log" 2>/dev/null; exit 1; }

port=$((20000 + RANDOM % 20000))
RW=rw-key-0123456789abcdef
cat > "$tmp/farm.ini" <<INI
[farm]
listen: 127.0.0.1:$port
data_dir: $tmp/data
api_keys: $RW
[printer mk3]
driver: marlin
port: pty:/dev/null
INI
export SLIMFARM_URL=http://127.0.0.1:$port SLIMFARM_API_KEY=$RW
"$D" -c "$tmp/farm.ini" >>"$tmp/log" 2>&1 &
pid=$!
up=
for _ in $(seq 200); do "$C" jobs >/dev/null 2>&1 && { up=1; break; }; sleep 0.05; done
[ -n "$up" ] || fail "daemon did not come up"

want="data dir '$tmp/data' is in use by another process (pid $pid)"
out=$("$D" -c "$tmp/farm.ini" 2>&1) && fail "a second daemon started"
[[ "$out" == *"$want"* ]] || fail "second daemon message: $out"
out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) && fail "--fsck ran beside a live daemon"
[[ "$out" == *"$want"* ]] || fail "--fsck message: $out"
"$C" jobs >/dev/null || fail "the live daemon stopped answering"

kill -TERM $pid; wait $pid; rc=$?; pid=
[ $rc -eq 0 ] || fail "SIGTERM exit status $rc"
out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) || fail "--fsck after the stop: $out"
[[ "$out" == *"store $tmp/data: ok"* ]] || fail "--fsck output: $out"
echo "farmd_lock: ok"
