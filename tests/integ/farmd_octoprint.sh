#!/usr/bin/env bash
# tests/integ/farmd_octoprint.sh - slimfarmd driving printers behind
# OctoPrint's REST API (slimfarm-sim octoprint, real loopback HTTP, real
# processes):
#  - a wrong api_key shows "authentication failed (check api_key)" on
#    `slimfarm printers`, and that printer never takes a job;
#  - jobs on the good printer end done and its executed log holds each
#    job's G-code once, in order, like the Marlin path (check_farm_logs);
#  - pause, resume (progress stands still in between) and cancel through
#    slimfarmd's REST API; the cancelled part waits for "cleared";
#  - a printer that answers 503 at first is offline with the reason, then
#    comes up; its first six uploads are cut half-way (libcurl re-sends an
#    upload whose reused connection died, up to 5 times, so the driver sees
#    one or two failures): the job is retried and ends done, never lost;
#  - an OctoPrint that stops answering mid-print (SIGSTOP: every request
#    times out) leaves the printer offline and the job interrupted; when
#    it answers again the job is re-attached and ends done;
#  - kill -9 of slimfarmd mid-print: the simulated OctoPrint prints on,
#    the restarted daemon re-attaches the job and it ends done, the file's
#    commands executed once.
# Every wait polls its condition with a generous bound (a loaded machine).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)
KEY=octo-key-0123456789

# start_octo NAME ARGS...: a simulated OctoPrint logging to $tmp/NAME.log;
# its URL lands in $tmp/NAME.addr (lib/netprint.sh: 30 s to start, not 5).
start_octo() {
  local name=$1; shift
  start_net "$name" octoprint --speed 2000 --uploads "$tmp/$name.up" "$@"
}
start_octo op --api-key "$KEY"
start_octo badkey --api-key "$KEY"
start_octo flaky --api-key "$KEY" --fault drop-upload=6 --fault 5xx=3@1
cp -r config/printers config/materials "$tmp/"
octo() { # NAME KEY MATERIAL
  printf '[printer %s]\ndriver: octoprint\nurl: %s\napi_key: %s\npoll_ms: 200\nmaterial: %s\nauto_eject: %s\n' \
    "$1" "$(cat "$tmp/$1.addr")" "$2" "$3" "${4:-false}"
}
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  octo op "$KEY" PLA
  octo badkey wrong-key-0123456789 PLA
  octo flaky "$KEY" PETG true
} > "$tmp/farm.ini"
"$D" --check -c "$tmp/farm.ini" > /dev/null || fail "--check refused the config: $("$D" --check -c "$tmp/farm.ini" 2>&1)"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^op +idle'" || fail "op not idle: $("$C" printers)"
wait_for 60 sh -c "'$C' printers | grep -qE '^flaky +idle'" || fail "flaky not idle: $("$C" printers)"
wait_for 60 sh -c "'$C' printers | grep -E '^badkey ' | grep -q 'authentication failed (check api_key)'" ||
  fail "no authentication error for badkey: $("$C" printers)"
"$C" printers | grep -qE '^badkey +offline' || fail "badkey not offline: $("$C" printers)"
grep -q "flaky.*answered HTTP 503" "$tmp/log" || fail "flaky's 503s left no trace in the daemon log"

"$C" shapes "$tmp" > /dev/null || fail "shapes"
tetra "$tmp/t10.stl" 10
tetra "$tmp/t12.stl" 12
j_a=$(submit "$tmp/t10.stl" --material PLA --printer op --method none)
j_long=$(submit "$tmp/lbracket.stl" --material PLA --printer op --method none)
j_cancel=$(submit "$tmp/frame.stl" --material PLA --printer op --method none)
j_flaky=$(submit "$tmp/t12.stl" --material PETG --printer flaky --method none --retries 5)

job_on() { # PRINTER: the job printing or paused on it
  api_jobs | json "' '.join(str(j['id']) for j in d['jobs'] if j['printer'] == '$1' and j['state'] in ('printing', 'paused'))"
}
# op clears its bed after each job (no ejector): clear it whenever it waits
clear_op() { "$C" printers | grep -qE '^op +awaiting-clear' && "$C" cleared op > /dev/null; return 0; }

# pause whichever long job op prints mid-print; the print stands still; resume
mid_print() {
  clear_op
  local j; j=$(job_on op)
  [ -n "$j" ] && [ "$j" != "$j_a" ] && [ "$(api "/api/jobs/$j" | json 'd["job"]["lines_acked"]')" -gt 0 ]
}
wait_for 240 mid_print || fail "op never got mid-print on a long job: $("$C" jobs)"
out=$("$C" pause op) || fail "pause: $out"
j_paused=$(job_on op)
[ "$(job_state "$j_paused")" = paused ] || fail "job $j_paused not paused: $(job_state "$j_paused")"
wait_for 20 sh -c "curl -sf -H 'X-Api-Key: $KEY' $(cat "$tmp/op.addr")/api/job | grep -q '\"state\":\"Paused\"'" ||
  fail "OctoPrint not paused: $(curl -s -H "X-Api-Key: $KEY" "$(cat "$tmp/op.addr")/api/job")"
p1=$(curl -sf -H "X-Api-Key: $KEY" "$(cat "$tmp/op.addr")/api/job" | json 'd["progress"]["filepos"]')
sleep 1
p2=$(curl -sf -H "X-Api-Key: $KEY" "$(cat "$tmp/op.addr")/api/job" | json 'd["progress"]["filepos"]')
[ "$p1" = "$p2" ] || fail "OctoPrint printed on while paused: $p1 -> $p2"
out=$("$C" resume op) || fail "resume: $out"
[ "$(job_state "$j_paused")" = printing ] || fail "job $j_paused not printing after resume"

# cancel the other long job once op prints it
j_other=$j_cancel; [ "$j_paused" = "$j_cancel" ] && j_other=$j_long
j_cancel=$j_other
cancel_ready() {
  clear_op
  [ "$(api "/api/jobs/$j_cancel" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]
}
wait_for 240 cancel_ready || fail "job $j_cancel never printed: $("$C" jobs)"
out=$("$C" cancel "$j_cancel") || fail "cancel: $out"
[ "$out" = "job $j_cancel: cancelled" ] || fail "cancel said: $out"
wait_for 60 sh -c "'$C' printers | grep -qE '^op +awaiting-clear'" || fail "op not awaiting clear after the cancel: $("$C" printers)"

# everything else ends done, flaky's job through a cut upload and 503s
all_done() {
  clear_op
  for j in $j_a $j_paused $j_flaky; do [ "$(job_state "$j")" = done ] || return 1; done
}
wait_for 300 all_done || fail "not all done: $("$C" jobs)"
[ "$(job_state "$j_cancel")" = cancelled ] || fail "cancelled job: $(job_state "$j_cancel")"
grep -q "upload failed" "$tmp/log" || fail "flaky's cut upload left no trace in the daemon log"
[ "$(api "/api/jobs/$j_flaky" | json 'len(d["prints"])')" -ge 2 ] || fail "flaky's job printed once only: the cut upload was not retried"
api "/api/jobs/$j_flaky" | json 'd["prints"][-1]["outcome"]' | grep -qx done || fail "flaky's last print not done"
"$C" printers | grep -qE '^badkey +offline' || fail "badkey: $("$C" printers)"
# so far each printer's log holds its prints' G-code once, in order, as the Marlin path does
clear_op
sleep 0.5
check_farm_logs op flaky || fail "executed logs differ from the jobs' G-code"

# OctoPrint stops answering mid-print: offline, interrupted; back: re-attached, done
j_stop=$(submit "$tmp/lbracket.stl" --material PLA --printer op --method none)
stop_ready() {
  clear_op
  [ "$(api "/api/jobs/$j_stop" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]
}
wait_for 240 stop_ready || fail "job $j_stop never printed: $("$C" jobs)"
kill -STOP $sim_op
wait_for 60 sh -c "'$C' printers | grep -qE '^op +offline .*unreachable'" || { kill -CONT $sim_op; fail "op not offline while OctoPrint is stopped: $("$C" printers)"; }
[ "$(job_state "$j_stop")" = interrupted ] || { kill -CONT $sim_op; fail "job $j_stop: $(job_state "$j_stop"), wanted interrupted"; }
kill -CONT $sim_op
wait_for 120 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_stop | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"job\"][\"state\"])')\" = done ]" ||
  fail "job $j_stop not done after OctoPrint came back: $("$C" jobs); $("$C" printers)"
grep -q "job $j_stop re-attached" "$tmp/log" || fail "no re-attach of job $j_stop in the daemon log"

# kill -9 mid-print: OctoPrint prints on, the restarted daemon re-attaches
j_kill=$(submit "$tmp/lbracket.stl" --material PLA --printer op --method none)
kill_ready() {
  clear_op
  [ "$(api "/api/jobs/$j_kill" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]
}
wait_for 240 kill_ready || fail "job $j_kill never printed: $("$C" jobs)"
kill -9 $pid; wait $pid 2>/dev/null; pid=
sleep 0.5
curl -sf -H "X-Api-Key: $KEY" "$(cat "$tmp/op.addr")/api/job" | grep -q '"state":"Printing"' ||
  echo "note: op finished before the daemon came back (the re-attach then ends it done at once)"
start_daemon
wait_for 120 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_kill | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"job\"][\"state\"])')\" = done ]" ||
  fail "job $j_kill not done after the restart: $("$C" jobs); $("$C" printers)"
grep -q "job $j_kill re-attached" "$tmp/log" || fail "no re-attach of job $j_kill in the daemon log"
[ "$(curl -sf -H "X-Api-Key: $KEY" "$(cat "$tmp/op.addr")/api/job" | json 'd["job"]["file"]["name"]')" != None ] || fail "op lost its job"

# the re-attached jobs: op's log ends with each one's G-code, once each
api "/api/jobs/$j_stop" > "$tmp/job-stop.json"
api "/api/jobs/$j_kill" > "$tmp/job-kill.json"
sleep 0.5
stop_sims
PYTHONPATH="$(dirname "$0")/lib" /usr/bin/python3 -B - "$tmp" <<'PY' || fail "op's log does not hold the re-attached jobs' G-code exactly once"
import os, sys
from gcodelog import commands, job_gcode
tmp = sys.argv[1]
got = commands(os.path.join(tmp, "op.log"))
(ks, ws), (kk, wk) = job_gcode(tmp, "job-stop.json"), job_gcode(tmp, "job-kill.json")
# the two were op's last prints, in this order, each whole and once
want = ws + wk
ok = len(got) >= len(want) and got[-len(want):] == want
print("  op: re-attached jobs %s and %s: %d + %d commands, %s" %
      (ks, kk, len(ws), len(wk), "ok" if ok else "MISMATCH"))
sys.exit(0 if ok else 1)
PY
# a clean stop: every driver, request and timer released (ASan checks leaks at exit)
kill -TERM $pid; wait $pid; rc=$?; pid=
[ $rc -eq 0 ] || fail "slimfarmd exited $rc on SIGTERM"
grep -q "LeakSanitizer\|AddressSanitizer" "$tmp/log" && fail "sanitizer report in the daemon log"
echo "farmd_octoprint: ok in $(( $(date +%s) - t0 )) s"
