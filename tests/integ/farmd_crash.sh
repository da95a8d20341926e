#!/usr/bin/env bash
# tests/integ/farmd_crash.sh - slimfarmd killed with SIGKILL 10 times at
# random moments while clients submit and cancel jobs; after each kill the
# store must recover and pass every check (slimfarmd --fsck), and every
# submission the daemon acknowledged must still be there, exactly once.
# (Killing while printing: farmd_crash_print.sh.)
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/daemon.sh"
D=$BUILD/bin/slimfarmd
C=$BUILD/bin/slimfarm
tmp=$(mktemp -d)
pid= lpid=
cleanup() { [ -n "$lpid" ] && kill "$lpid" 2>/dev/null; [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null && wait "$pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; tail -20 "$tmp/log" 2>/dev/null; exit 1; }

RW=rw-key-0123456789abcdef
cat > "$tmp/farm.ini" <<INI
[farm]
listen: 127.0.0.1:0
data_dir: $tmp/data
api_keys: $RW
[printer mk3]
driver: marlin
port: pty:/dev/null
INI
export SLIMFARM_API_KEY=$RW
printf 'solid t\nfacet normal 0 0 -1\nouter loop\nvertex 0 0 0\nvertex 0 10 0\nvertex 10 0 0\nendloop\nendfacet\nfacet normal 0 -1 0\nouter loop\nvertex 0 0 0\nvertex 10 0 0\nvertex 0 0 10\nendloop\nendfacet\nfacet normal -1 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0 10\nvertex 0 10 0\nendloop\nendfacet\nfacet normal 1 1 1\nouter loop\nvertex 10 0 0\nvertex 0 10 0\nvertex 0 0 10\nendloop\nendfacet\nendsolid t\n' > "$tmp/p.stl"

# Client loop: submit, and cancel every third job; record acknowledged ids.
client() {
  while true; do
    out=$("$C" submit "$tmp/p.stl" --method none 2>/dev/null) || continue
    id=$(echo "$out" | sed -n 's/^job \([0-9]*\) queued.*/\1/p')
    [ -n "$id" ] && echo "$id" >> "$tmp/acked"
    [ -n "$id" ] && [ $((id % 3)) -eq 0 ] && "$C" cancel "$id" >/dev/null 2>&1
  done
}

: > "$tmp/acked"
for round in $(seq 10); do
  daemon_start "$tmp/farm.ini" "$tmp/log" || fail "round $round: the daemon did not come up"
  for _ in $(seq 100); do "$C" jobs >/dev/null 2>&1 && break; sleep 0.05; done
  before=$(wc -l < "$tmp/acked")
  client & lpid=$!
  # kill at a random moment once the clients are under way (a loaded host
  # may take seconds to answer the first submission of a sanitizer build)
  for _ in $(seq 200); do [ "$(wc -l < "$tmp/acked")" -gt "$before" ] && break; sleep 0.05; done
  sleep "0.$((RANDOM % 7))"
  kill -9 $pid; wait $pid 2>/dev/null; pid=
  kill $lpid; wait $lpid 2>/dev/null; lpid=
  out=$("$D" -c "$tmp/farm.ini" --fsck 2>&1) || fail "round $round: fsck: $out"
  n=$(echo "$out" | sed -n 's/.*ok, \([0-9]*\) jobs.*/\1/p')
  acked=$(sort -u "$tmp/acked" | wc -l)
  dup=$(sort "$tmp/acked" | uniq -d | wc -l)
  [ "$dup" -eq 0 ] || fail "round $round: a job id was acknowledged twice"
  # every acknowledged job exists; beyond them at most one per kill (committed,
  # then killed before the reply reached the client)
  [ "$n" -ge "$acked" ] && [ "$n" -le $((acked + round)) ] || fail "round $round: $n jobs in store, $acked acknowledged"
done
[ "$(wc -l < "$tmp/acked")" -ge 2 ] || fail "clients got too little done: $(wc -l < "$tmp/acked")"
# the daemon comes back a last time and lists them all
daemon_start "$tmp/farm.ini" "$tmp/log" || fail "the daemon did not come back"
for _ in $(seq 100); do "$C" jobs >/dev/null 2>&1 && break; sleep 0.05; done
while read -r id; do
  "$C" jobs | grep -qE "^$id " || fail "acknowledged job $id missing"
done < "$tmp/acked"
echo "farmd_crash: ok ($(wc -l < "$tmp/acked") jobs acknowledged over 10 kills)"
