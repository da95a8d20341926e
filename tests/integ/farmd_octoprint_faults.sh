#!/usr/bin/env bash
# tests/integ/farmd_octoprint_faults.sh - printer-side faults behind
# OctoPrint (slimfarm-sim octoprint --fault ...), each leaving a clear
# printer state and the job retried or waiting, never lost:
#  - error-at: the printer fails mid-print ("Error"): the printer shows
#    error with OctoPrint's message, the job's print failed and the job is
#    waiting for its retry; once OctoPrint is reconnected (operational
#    again) and the error acknowledged ("cleared"), the retry prints and
#    the job is done;
#  - cancel-at: the print is cancelled at the printer (every time, at the
#    same line): each print fails "stopped at the printer", the job is
#    retried as often as it may, then fails saying why;
#  - busy: OctoPrint says it is printing something else: the printer is
#    not idle, says so, and takes no job (the job waits, queued or ready).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)
KEY=octo-key-0123456789

# start_octo NAME ARGS...: lib/netprint.sh's start_net (30 s to start, not 5)
start_octo() {
  local name=$1; shift
  start_net "$name" octoprint --api-key "$KEY" --speed 2000 "$@"
}
start_octo err --fault error-at=300
start_octo stop --fault cancel-at=300
start_octo busy --fault busy=1
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  for p in err stop busy; do
    m=PLA; [ $p = stop ] && m=PETG
    printf '[printer %s]\ndriver: octoprint\nurl: %s\napi_key: %s\npoll_ms: 200\nmaterial: %s\nauto_eject: true\n' \
      "$p" "$(cat "$tmp/$p.addr")" "$KEY" "$m"
  done
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^err +idle'" || fail "err not idle: $("$C" printers)"
wait_for 60 sh -c "'$C' printers | grep -qE '^stop +idle'" || fail "stop not idle: $("$C" printers)"
wait_for 60 sh -c "'$C' printers | grep -E '^busy ' | grep -q 'OctoPrint is busy'" ||
  fail "busy does not say it is busy: $("$C" printers)"

"$C" shapes "$tmp" > /dev/null || fail "shapes"
j_err=$(submit "$tmp/lbracket.stl" --material PLA --printer err --method none --retries 2)
j_stop=$(submit "$tmp/lbracket.stl" --material PETG --printer stop --method none --retries 2)
j_busy=$(submit "$tmp/lbracket.stl" --material PLA --printer busy --method none)

# error-at: error state with the printer's message; the job waits for its retry
wait_for 240 sh -c "'$C' printers | grep -qE '^err +error .*heater failure'" ||
  fail "err not in error: $("$C" printers); $("$C" jobs)"
st=$(job_state "$j_err")
case $st in ready|queued|preparing) ;; *) fail "job $j_err after the printer error: $st" ;; esac
api "/api/jobs/$j_err" | json 'd["prints"][0]["outcome"]' | grep -qx failed || fail "err's print not failed"
# the operator reconnects OctoPrint to its printer, then clears the error:
# the retry prints and the job is done
curl -sf -X POST -H "X-Api-Key: $KEY" -H 'Content-Type: application/json' \
  -d '{"command":"connect"}' "$(cat "$tmp/err.addr")/api/connection" || fail "connect"
wait_for 30 sh -c "curl -sf -H 'X-Api-Key: $KEY' $(cat "$tmp/err.addr")/api/job | grep -q Operational" || fail "sim still in error"
"$C" cleared err > /dev/null || fail "cleared err"
wait_for 300 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_err | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"job\"][\"state\"])')\" = done ]" ||
  fail "job $j_err not done after the error was cleared: $("$C" jobs); $("$C" printers)"

# cancel-at: every print is stopped at the printer at the same line, so the
# job uses its retries and ends failed, with the reason, never silently
wait_for 300 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_stop | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"job\"][\"state\"])')\" = failed ]" ||
  fail "job $j_stop: $(job_state "$j_stop")"
api "/api/jobs/$j_stop" | json 'd["job"]["reason"]' | grep -q "stopped at the printer" ||
  fail "job $j_stop reason: $(api "/api/jobs/$j_stop" | json 'd["job"]["reason"]')"
[ "$(api "/api/jobs/$j_stop" | json 'len(d["prints"])')" = 3 ] ||
  fail "job $j_stop was not retried twice: $(api "/api/jobs/$j_stop")"

# busy: nothing started there
st=$(job_state "$j_busy")
case $st in ready|queued|preparing) ;; *) fail "job $j_busy on a busy printer: $st" ;; esac
"$C" printers | grep -qE '^busy +offline' || fail "busy: $("$C" printers)"
echo "farmd_octoprint_faults: ok in $(( $(date +%s) - t0 )) s"
