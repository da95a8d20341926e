#!/usr/bin/env bash
# tests/integ/farmd_bambu_upload.sh - a Bambu printer's links cut under a
# job, at the daemon's level:
#  - the simulated printer's FTPS data connection dies after 4 kB of the
#    first package (--fault ftps-drop=4096, once: TLS dropped under the
#    transfer): slimfarmd fails that print with the upload's error and
#    retries it (the job's retry budget); the second upload goes through;
#  - then, 10 reports into the print, the printer's MQTT goes away for half
#    a second, cutting the daemon's connection through the printer's MQTT
#    port (--fault mqtt-drop=10): the printer goes offline, the job is
#    interrupted, not failed, and when the daemon has reconnected (its
#    backoff) the job is re-attached from the reports and ends done.
# Nothing lost or doubled: the printer stored one package, started one
# job, and its executed log is the job's G-code exactly once.
# Skips (exit 0 with a note) when mosquitto or openssl is missing.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
CODE=14142135
. "$(dirname "$0")/lib/bambu.sh"
t0=$(date +%s)

bambu_printer x1 01S00C0000000077 x1 300 --fault ftps-drop=4096 --fault mqtt-drop=10
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  bambu_ini x1 "$mqtt_x1" # through the printer's own port: mqtt-drop cuts it
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^x1 +idle'" || fail "x1: $("$C" printers)"

tetra "$tmp/t14.stl" 14
j=$(submit "$tmp/t14.stl" --material PLA --printer x1 --method none)
is_done() { [ "$(job_state "$j")" = done ]; }
wait_for 300 is_done || fail "job $j not done: $("$C" jobs); $("$C" printers)"
api "/api/jobs/$j" > "$tmp/job.json"
/usr/bin/python3 - "$tmp/job.json" <<'PY' || fail "job $j's prints: $(cat "$tmp/job.json")"
import json, sys
d = json.load(open(sys.argv[1]))
prints = sorted(d["prints"], key=lambda p: p["started_ms"])
outcomes = [p["outcome"] for p in prints]
# the cut upload failed; the retry was interrupted by the MQTT drop and re-attached
if len(outcomes) < 2 or outcomes[0] != "failed" or outcomes[-1] != "done" or "failed" in outcomes[1:]:
    sys.exit("prints %r, wanted a failed upload, then done (re-attached)" % outcomes)
print("  job %d: prints %s" % (d["job"]["id"], outcomes))
PY
grep -m 1 "upload failed" "$tmp/log" || fail "no upload failure in the daemon log"
grep -m 1 "MQTT: connection lost" "$tmp/log" || fail "the daemon never lost MQTT"
grep -qE "job $j re-attached" "$tmp/log" || fail "no re-attach of job $j in the daemon log"
sleep 0.5
kill "$sim_x1"; wait "$sim_x1" 2>/dev/null; sims=()
grep -q "uploads=1 " "$tmp/x1.err" || fail "the printer stored other than one package: $(grep stats: "$tmp/x1.err")"
grep -q "jobs_started=1 " "$tmp/x1.err" || fail "the printer started other than one job: $(grep stats: "$tmp/x1.err")"
PYTHONPATH="$(dirname "$0")/lib" /usr/bin/python3 -B - "$tmp" <<'PY' || fail "x1's log is not the job's G-code exactly once"
import os, sys
from gcodelog import commands, job_gcode
tmp = sys.argv[1]
want = job_gcode(tmp, "job.json")[1]
got = commands(os.path.join(tmp, "x1.log"))
if got != want:
    print("log: %d lines, G-code: %d" % (len(got), len(want)))
    sys.exit(1)
print("  x1: %d log lines, the job once" % len(got))
PY
kill -TERM $pid; wait $pid; pid=
echo "farmd_bambu_upload: ok (upload cut at 4 kB and retried, MQTT cut mid-print and re-attached, done, in $(( $(date +%s) - t0 )) s)"
