#!/usr/bin/env bash
# tests/integ/farmd_bambu_crash.sh - a Bambu print outlives its host links:
#  - kill -9 of slimfarmd mid-print: the simulated printer prints on, the
#    restarted daemon re-attaches the job from the report and it ends done;
#  - then the broker restarts mid-print: the printer goes offline, the job
#    is interrupted (not failed: the printer prints on), and when the broker
#    is back the driver reconnects, re-subscribes, asks for the whole state
#    (pushall) and the job is re-attached and ends done.
# The printer's log then holds each job's G-code exactly once, in order.
# Skips (exit 0 with a note) when mosquitto or openssl is missing.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
CODE=16180339
. "$(dirname "$0")/lib/bambu.sh"
t0=$(date +%s)

bambu_printer x1 01S00C0000000042 p1 150
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  bambu_ini x1 "$broker_x1" # through the broker itself: it restarts below
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^x1 +idle'" || fail "x1: $("$C" printers)"
"$C" shapes "$tmp" > /dev/null || fail "shapes"

printing() { [ "$(api "/api/jobs/$1" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]; }
is_done() { [ "$(job_state "$1")" = done ]; }

# kill -9 of the daemon mid-print
j_kill=$(submit "$tmp/frame.stl" --material PLA --printer x1 --method none)
wait_for 240 printing "$j_kill" || fail "job $j_kill never printed: $("$C" jobs)"
kill -9 $pid; wait $pid 2>/dev/null; pid=
start_daemon
wait_for 600 is_done "$j_kill" || fail "job $j_kill not done after the restart: $("$C" jobs); $("$C" printers)"
grep -q "job $j_kill re-attached" "$tmp/log" || fail "no re-attach of job $j_kill in the daemon log"

# the broker restarts mid-print
j_broker=$(submit "$tmp/lbracket.stl" --material PLA --printer x1 --method none)
wait_for 240 printing "$j_broker" || fail "job $j_broker never printed: $("$C" jobs)"
bambu_broker_stop x1
wait_for 60 sh -c "'$C' printers | grep -qE '^x1 +offline'" || fail "x1 not offline without its broker: $("$C" printers)"
st=$(job_state "$j_broker")
[ "$st" = interrupted ] || [ "$st" = done ] || fail "job $j_broker: $st, wanted interrupted"
bambu_broker_start x1 "$broker_x1"
wait_for 600 is_done "$j_broker" || fail "job $j_broker not done after the broker came back: $("$C" jobs); $("$C" printers)"
grep -q "job $j_broker re-attached" "$tmp/log" || fail "no re-attach of job $j_broker in the daemon log"
api "/api/jobs/$j_kill" > "$tmp/job-a.json"
api "/api/jobs/$j_broker" > "$tmp/job-b.json"
sleep 0.5
stop_sims
PYTHONPATH="$(dirname "$0")/lib" /usr/bin/python3 -B - "$tmp" <<'PY' || fail "x1's log does not hold the jobs' G-code exactly once"
import os, sys
from gcodelog import commands, job_gcode
tmp = sys.argv[1]
want = []
for name in ("job-a.json", "job-b.json"):
    if os.path.exists(os.path.join(tmp, name)):
        want += job_gcode(tmp, name)[1]
got = commands(os.path.join(tmp, "x1.log"))
if got != want:
    i = next((k for k in range(min(len(got), len(want))) if got[k] != want[k]), min(len(got), len(want)))
    print("log differs at line %d: %r vs %r (%d vs %d lines)" % (i + 1, got[i:i + 2], want[i:i + 2], len(got), len(want)))
    sys.exit(1)
print("  x1: %d log lines, both jobs once each" % len(got))
PY
kill -TERM $pid; wait $pid; pid=
echo "farmd_bambu_crash: ok (kill -9 mid-print, re-attached; broker restart, re-attached, in $(( $(date +%s) - t0 )) s)"
