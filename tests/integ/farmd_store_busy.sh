#!/usr/bin/env bash
# tests/integ/farmd_store_busy.sh - a print keeps streaming while another
# process holds the store's database busy (issue 32: the loop never waits
# on the store).  A real slimfarmd prints a long G-code job on a simulated
# Marlin; mid-print a Python process takes SQLite's write lock (BEGIN
# EXCLUSIVE; on PostgreSQL, make check-pg, psql locks the jobs and prints
# tables) and holds it until the simulator has executed LINES more lines.
# Before the store thread, every progress write (one each 16 lines) waited
# out the 5 s busy timeout on the loop, so the stream crawled at about 16
# lines per 5 s and the wait ran out.  While locked the API answers too.
# After the lock goes the job ends done, its print record has every line,
# and the printer's executed log is the job's commands once each, in order
# (check_farm_logs).  Under the lock an operator pauses and resumes the
# print and adds a job through the API: the printer pauses and resumes at
# once, the answers come only once the lock goes (200, 201, 200), the
# added job exists once.  /metrics shows a write was held up and retried,
# none failed; the loop's longest turn is printed for the record, not
# asserted.
set -u
BUILD=${BUILD:-build/san}
LINES=${LINES:-2000}
LOCK=${BUSY_LOCK:-1} # 0: the same print and window, no lock (bench_store_busy.sh's baseline)
. "$(dirname "$0")/lib/farm.sh"

start_sim mk3 --speed 2000
one_printer_ini mk3 true
printf 'material: PLA\ngcode_models: *\n' >> "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^mk3 +idle'" || fail "mk3: $("$C" printers)"

# 40,000 short moves: minutes at the simulator's pace, so the lock lands mid-print
awk 'BEGIN { print "G90"; print "M83";
  for (i = 0; i < 40000; i++) printf "G1 X%.2f Y%.2f E0.01 F6000\n", 50 + (i % 100) * 0.5, 50 + (i % 7) }' \
  > "$tmp/long.gcode"
c=$(curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -F print=true -F path= \
  -F "file=@$tmp/long.gcode;filename=long.gcode" "$SLIMFARM_URL/api/files/local")
[ "$c" = 201 ] || fail "upload: $c $(cat "$tmp/r")"
id=$(json 'd["slimfarm"]["job_id"]' < "$tmp/r")

# executed: the simulator's count of commands run (SIGUSR1 prints a stats line)
executed() {
  local n before
  before=$(grep -c '^stats: ' "$tmp/mk3.err")
  kill -USR1 "${sims[0]}"
  for _ in $(seq 600); do
    n=$(grep -c '^stats: ' "$tmp/mk3.err")
    [ "$n" -gt "$before" ] && break
    sleep 0.05
  done
  grep '^stats: ' "$tmp/mk3.err" | tail -n 1 | sed -n 's/.* executed=\([0-9]*\) .*/\1/p'
}
past() { [ "$(executed)" -ge "$1" ]; }
wait_for 120 past 500 || fail "the print did not start: $("$C" jobs)"

# the lock: held from "locked" until "release" appears (or 300 s)
[ "$LOCK" = 1 ] || touch "$tmp/locked"
# (on PostgreSQL, make check-pg: a psql session's lock on the tables a print writes, which
# the daemon's writes wait for as long as its lock_timeout, then retry)
pg_lock() {
  echo "BEGIN; LOCK TABLE jobs, prints IN EXCLUSIVE MODE;"
  echo "\\! touch '$tmp/locked'" # run once the lock is held
  local end=$((SECONDS + 300))
  while [ ! -e "$tmp/release" ] && [ $SECONDS -lt $end ]; do sleep 0.05; done
  echo "ROLLBACK;"
}
if [ "$LOCK" = 1 ] && [ -n "${SLIMFARM_TEST_STORE:-}" ]; then
  pg_lock | psql -q -v ON_ERROR_STOP=1 "$(daemon_db "$tmp/farm.ini")" > "$tmp/locker.out" 2>&1 &
elif [ "$LOCK" = 1 ]; then
  /usr/bin/python3 - "$tmp/data/slimfarm.db" "$tmp" <<'PY' > "$tmp/locker.out" 2>&1 &
import os, sqlite3, sys, time
db = sqlite3.connect(sys.argv[1], timeout=60, isolation_level=None)
db.execute("BEGIN EXCLUSIVE")
open(os.path.join(sys.argv[2], "locked"), "w").close()
end = time.time() + 300
while not os.path.exists(os.path.join(sys.argv[2], "release")) and time.time() < end:
    time.sleep(0.05)
db.execute("ROLLBACK")
PY
fi
locker=$!
wait_for 120 test -e "$tmp/locked" || fail "no lock: $(cat "$tmp/locker.out")"
from=$(executed)
t_lock=$SECONDS t0=$(date +%s.%N)
# the stream goes on under the lock: LINES more lines before it is let go
wait_for 120 past $((from + LINES)) || {
  touch "$tmp/release"
  fail "while the store was locked the printer ran $(($(executed) - from)) lines in $((SECONDS - t_lock)) s"
}
ran=$(($(executed) - from))
secs=$(printf '%.2f' "$(echo "$(date +%s.%N) - $t0" | bc)")
"$C" jobs > /dev/null || fail "the API did not answer while the store was locked"
metric() { curl -sf -H "X-Api-Key: $RW" "$SLIMFARM_URL/metrics" | sed -n "s/^$1 //p"; }

# An operator's writes under the lock (the loop never waits for them): a pause, a job added
# (ABS: no printer takes it, it stays queued), a resume.  The printer acts at once; each
# answer comes once its write has committed, so none before the lock goes.
post() { # post NAME PATH [CURL ARGS...]: in the background, its status into $tmp/NAME.code
  local name=$1 path=$2; shift 2
  (curl -s -o "$tmp/$name.body" -w '%{http_code}' -H "X-Api-Key: $RW" "$@" \
    "$SLIMFARM_URL$path" > "$tmp/$name.code.part"; mv "$tmp/$name.code.part" "$tmp/$name.code") &
}
state_is() { "$C" printers | grep -qE "^mk3 +$1"; }
if [ "$LOCK" = 1 ]; then
  post pause /api/printers/mk3/pause -X POST
  wait_for 60 state_is paused || fail "mk3 did not pause under the lock: $("$C" printers)"
  paused_at=$(executed)
  printf 'v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n' > "$tmp/abs.obj"
  post add /api/jobs -F "file=@$tmp/abs.obj;filename=abs-part.obj" -F 'options={"material": "ABS"}'
  post resume /api/printers/mk3/resume -X POST
  wait_for 60 state_is printing || fail "mk3 did not resume under the lock: $("$C" printers)"
  sleep 1 # the answers would have come by now if they did not wait for the store
  for n in pause add resume; do
    [ -e "$tmp/$n.code" ] && fail "the $n was answered ($(cat "$tmp/$n.code")) while the store was locked"
  done
  # the print goes on after the resume, still under the lock
  wait_for 120 past $((paused_at + 200)) || fail "mk3 did not print on after its resume under the lock"
fi
if [ "$LOCK" = 1 ]; then
  # and the store was busy for the daemon: a write failed on the lock and waits to be tried again
  retried() { [ "$(metric slimfarm_store_write_retries_total)" -ge 1 ] 2> /dev/null; }
  wait_for 120 retried || { touch "$tmp/release"; fail "no store write waited for the lock"; }
  [ "$(metric slimfarm_store_queue_depth)" -ge 1 ] || fail "nothing queued behind the lock"
  kill -0 "$locker" 2> /dev/null || fail "the lock ended early: $(cat "$tmp/locker.out")"
  touch "$tmp/release"
  wait "$locker" || fail "locker: $(cat "$tmp/locker.out")"
  for n in pause add resume; do
    wait_for 120 test -e "$tmp/$n.code" || fail "the $n was not answered once the lock went"
  done
  [ "$(cat "$tmp/pause.code") $(cat "$tmp/add.code") $(cat "$tmp/resume.code")" = "200 201 200" ] ||
    fail "answers: pause $(cat "$tmp/pause.code") $(cat "$tmp/pause.body"); add $(cat "$tmp/add.code") $(cat "$tmp/add.body"); resume $(cat "$tmp/resume.code") $(cat "$tmp/resume.body")"
  added=$(json 'd["job"]["id"]' < "$tmp/add.body")
  # the added job exists once, queued
  n_abs=$(api_jobs | json 'len([j for j in d["jobs"] if j["name"] == "abs-part.obj"])')
  [ "$n_abs" = 1 ] || fail "the added job is there $n_abs times"
  st=$(api "/api/jobs/$added" | json 'd["job"]["state"]')
  [ "$st" = queued ] || fail "the added job is $st"
fi
held=$((SECONDS - t_lock))

wait_for 600 sh -c "[ \"\$('$C' jobs | awk '\$1 == $id { print \$2 }')\" = done ]" ||
  fail "job $id did not end done: $("$C" jobs)"
acked=$(api "/api/jobs/$id" | json '"%s %d %d" % (d["prints"][-1]["outcome"], d["prints"][-1]["lines_acked"], len(d["prints"]))')
[ "$acked" = "done 40002 1" ] || fail "job $id's prints: $acked (want one, done at line 40002)"
turn=$(metric slimfarm_loop_turn_max_seconds)
retries=$(metric slimfarm_store_write_retries_total)
fails=$(metric slimfarm_store_write_failures_total)
[ "$fails" = 0 ] || fail "$fails store writes failed"
stop_sims
check_farm_logs mk3 || fail "mk3's executed log is not the job's"
kill -TERM $pid; wait $pid; pid=
echo "farmd_store_busy: ok ($([ "$LOCK" = 1 ] && echo "the store locked for $held s" || echo "no lock"): the printer ran $ran lines in $secs s; $retries writes retried, none lost; longest loop turn $turn s)"
echo "window: lock=$LOCK lines=$ran secs=$secs turn_max_s=$turn retries=$retries"
