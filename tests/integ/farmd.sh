#!/usr/bin/env bash
# tests/integ/farmd.sh - slimfarmd and the slimfarm client end to end over
# loopback: config check, submit (with options, read-only key refused,
# traversal refused by the daemon), jobs/printers listings, live events,
# cancel, SIGHUP reload (good and broken config), kill -9 and restart with
# nothing lost, SIGTERM.  The printer's port is /dev/null, no printer at
# all: it must stay offline and say why (printing is tested with simulated
# printers elsewhere).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/daemon.sh"
D=$BUILD/bin/slimfarmd
C=$BUILD/bin/slimfarm
tmp=$(mktemp -d)
pid=
cleanup() { [ -n "$pid" ] && kill -9 "$pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; echo "--- daemon log"; cat "$tmp/log" 2>/dev/null; exit 1; }
# Run "$@" until it succeeds, for up to 20 s: states are waited for, never slept for.
eventually() { for _ in $(seq 400); do "$@" && return 0; sleep 0.05; done; return 1; }
jobs_match() { "$C" jobs "${@:2}" 2>/dev/null | grep -qE "$1"; }

RW=rw-key-0123456789abcdef
RO=ro-key-0123456789abcdef
cat > "$tmp/farm.ini" <<INI
[farm]
listen: 127.0.0.1:0
data_dir: $tmp/data
api_keys: $RW
api_keys_readonly: $RO
upload_max_mb: 1
[printer mk3]
driver: marlin
port: pty:/dev/null
material: PLA
INI
export SLIMFARM_API_KEY=$RW

"$D" -c "$tmp/farm.ini" --check | grep -q "ok, 1 printers, 2 API keys" || fail "--check"
printf '[printer x]\nbaud_rate: 1\n' > "$tmp/bad.ini"
out=$("$D" -c "$tmp/bad.ini" 2>&1) && fail "bad config accepted"
[[ "$out" == *"bad.ini:2: option 'baud_rate' is not valid in section 'printer x'"* ]] || fail "bad config message: $out"

start() { # a port the kernel picks, each start its own (lib/daemon.sh)
  daemon_start "$tmp/farm.ini" "$tmp/log" || fail "daemon did not come up"
  for _ in $(seq 100); do "$C" jobs >/dev/null 2>&1 && return 0; sleep 0.05; done
  fail "daemon did not come up"
}
start

cat > "$tmp/bracket.stl" <<STL
solid t
facet normal 0 0 -1
outer loop
vertex 0 0 0
vertex 0 10 0
vertex 10 0 0
endloop
endfacet
facet normal 0 -1 0
outer loop
vertex 0 0 0
vertex 10 0 0
vertex 0 0 10
endloop
endfacet
facet normal -1 0 0
outer loop
vertex 0 0 0
vertex 0 0 10
vertex 0 10 0
endloop
endfacet
facet normal 1 1 1
outer loop
vertex 10 0 0
vertex 0 10 0
vertex 0 0 10
endloop
endfacet
endsolid t
STL
out=$("$C" submit "$tmp/bracket.stl" --copies 2 --material NYLON --method surface --priority 3) || fail "submit: $out"
[ "$out" = "job 1 queued: bracket.stl x2" ] || fail "submit said: $out"
out=$("$C" submit "$tmp/bracket.stl" --copies 0 2>&1) && fail "copies 0 accepted"
[[ "$out" == *"400: options: copies: 0 is not in 1..1000"* ]] || fail "copies 0: $out"
out=$("$C" submit "$tmp/bracket.stl" --key $RO 2>&1) && fail "read-only key could submit"
[[ "$out" == *"403: read-only API key"* ]] || fail "read-only: $out"
out=$("$C" jobs --key nope-nope-nope-nope 2>&1) && fail "bad key accepted"
[[ "$out" == *"401: unknown API key"* ]] || fail "bad key: $out"
code=$(curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -F "file=@$tmp/bracket.stl;filename=../../x.stl" "$SLIMFARM_URL/api/jobs")
[ "$code" = 400 ] && grep -q "not a plain file name" "$tmp/r" || fail "traversal: $code $(cat "$tmp/r")"
head -c 2000000 /dev/zero > "$tmp/huge.stl"
out=$("$C" submit "$tmp/huge.stl" 2>&1) && fail "oversized upload accepted"
[[ "$out" == *"413: "* ]] || fail "oversized: $out"

eventually jobs_match "^1 +queued .*fits no printer" --key $RO
out=$("$C" jobs --key $RO) || fail "jobs"
echo "$out" | grep -qE "^1 +queued +0/2 +- +3 .*bracket.stl +fits no printer: mk3: material NYLON not loaded \(has PLA\)" || fail "jobs: $out"
out=$("$C" printers) || fail "printers"
echo "$out" | grep -qE "^mk3 +offline .*'/dev/null' is not a terminal" || fail "printers: $out"

# orient + slice for real (config/printers, config/materials); waits for mk3
cp -r config/printers config/materials "$tmp/"
out=$("$C" submit "$tmp/bracket.stl" --method orient) || fail "submit orient: $out"
eventually jobs_match '^2 +ready'
"$C" jobs | grep -qE '^2 +ready .*waits for a printer: mk3 is offline' || fail "orient job: $("$C" jobs)"

# a part that is no mesh by its content is refused at upload, saying why
# (nothing is queued); one that holds no facet fails at once
echo "not a mesh" > "$tmp/junk.stl"
out=$("$C" submit "$tmp/junk.stl" 2>&1) && fail "junk part accepted: $out"
[[ "$out" == *"400: not an STL: 'junk.stl' holds plain text"* ]] || fail "junk part: $out"
printf 'solid empty\nendsolid empty\n' > "$tmp/empty.stl"
"$C" submit "$tmp/empty.stl" >/dev/null || fail "submit empty"
eventually jobs_match "^3 +failed .*empty.stl" || fail "empty part: $("$C" jobs)"

# live events: the watcher sees a submission and a cancel made after it
# started.  It resumes after the newest event so far (which an event id past
# the log's end makes the daemon name in its reset event), so it cannot miss
# them however late it connects.
newest=$(curl -sN --max-time 20 -H "X-Api-Key: $RW" -H "Last-Event-ID: 999999999" "$SLIMFARM_URL/api/events" |
  sed -n 's/^data: {"last_event_id":999999999,"newest":\([0-9]*\),.*/\1/p;T;q')
[ -n "$newest" ] || fail "no newest event id from the reset event"
"$C" watch --count 2 --since "$newest" > "$tmp/watch" 2>&1 &
wpid=$!
"$C" submit "$tmp/bracket.stl" >/dev/null || fail "second submit"
out=$("$C" cancel 4) || fail "cancel: $out"
[ "$out" = "job 4: cancelled" ] || fail "cancel said: $out"
eventually eval '! kill -0 $wpid 2>/dev/null'
kill $wpid 2>/dev/null && fail "watch did not end after 2 events"
grep -q "job-add" "$tmp/watch" || fail "watch: $(cat "$tmp/watch")"
out=$("$C" cancel 4 2>&1) && fail "cancelled twice"
[[ "$out" == *"409: job 4: cannot cancel a cancelled job"* ]] || fail "double cancel: $out"
out=$("$C" pause mk3 2>&1) && fail "paused an offline printer"
[[ "$out" == *"503: printer mk3 is offline"* ]] || fail "pause offline: $out"
out=$("$C" cleared nosuch 2>&1) && fail "unknown printer"
[[ "$out" == *"404: no printer 'nosuch'"* ]] || fail "unknown printer: $out"

# SIGHUP: a broken config is refused and the old one kept; a good one applies
cp "$tmp/farm.ini" "$tmp/good.ini"
printf '[printer y]\ncolour: red\n' >> "$tmp/farm.ini"
kill -HUP $pid
eventually grep -q "reload: " "$tmp/log"
grep -q "reload: .*farm.ini:[0-9]*: option 'colour' is not valid in section 'printer y'; keeping" "$tmp/log" || fail "bad reload not reported"
cp "$tmp/good.ini" "$tmp/farm.ini"
printf '[printer voron]\ndriver: marlin\nport: tcp://127.0.0.1:1\nmaterial: PETG\n' >> "$tmp/farm.ini"
kill -HUP $pid
eventually grep -q "reloaded " "$tmp/log"
"$C" printers | grep -q "^voron " || fail "reload did not add voron: $("$C" printers)"

# kill -9 and restart: every job where it was
kill -9 $pid; wait $pid 2>/dev/null; pid=
start
out=$("$C" jobs)
echo "$out" | grep -qE '^1 +queued +0/2' || fail "job 1 after restart: $out"
echo "$out" | grep -qE '^2 +ready' || fail "job 2 after restart: $out"
echo "$out" | grep -qE '^3 +failed' || fail "job 3 after restart: $out"
echo "$out" | grep -qE '^4 +cancelled' || fail "job 4 after restart: $out"
[ "$(echo "$out" | wc -l)" -eq 5 ] || fail "job count after restart: $out"

kill -TERM $pid; wait $pid; rc=$?; pid=
[ $rc -eq 0 ] || fail "SIGTERM exit status $rc"
grep -q "signal 15: stopping" "$tmp/log" || fail "no stop message"
echo "farmd: ok"
