#!/usr/bin/env bash
# tests/integ/farmd_octoprint_face.sh - slimfarmd's own OctoPrint face as
# OctoPrint clients written by others see it (issue 35): each session in
# tests/replay/farmd/ (FDM Monster's with a read-write key, a status app's
# with a read-only key) is replayed by tests/replay/replay.py against a
# daemon with one simulated Marlin printer over real loopback HTTP, and
# every answer's status and shape is checked: passive login and the current
# user mapped from the key's rights, the farm as one printer (Operational,
# Printing while a job prints), the job list as OctoPrint files newest
# first, POST /api/job cancel of the one printing job.  Each wait is an
# UNTIL with a generous bound (a loaded machine).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
t0=$(date +%s)
dir=$(dirname "$0")/../replay
RO=ro-key-0123456789abcdef
# real time: the replayed G-code prints for seconds, long enough to be seen printing
start_sim mk --speed 1
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf 'api_keys_readonly: %s\n' "$RO"
  printf '[printer mk]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$(cat "$tmp/mk.addr")"
  printf 'auto_eject: true\ngcode_models: *\n'
} > "$tmp/farm.ini"
start_daemon
/usr/bin/python3 "$dir/replay.py" "$SLIMFARM_URL" "$RW" "$dir/farmd/octoprint-fdmmonster.txt" ||
  fail "FDM Monster's session: slimfarmd does not answer as the client expects"
/usr/bin/python3 "$dir/replay.py" "$SLIMFARM_URL" "$RO" "$dir/farmd/octoprint-readonly.txt" ||
  fail "the read-only session: slimfarmd does not answer as the client expects"
kill -TERM $pid; wait $pid; rc=$?; pid=
[ $rc -eq 0 ] || fail "slimfarmd exited $rc on SIGTERM"
grep -q "LeakSanitizer\|AddressSanitizer" "$tmp/log" && fail "sanitizer report in the daemon log"
echo "farmd_octoprint_face: ok in $(( $(date +%s) - t0 )) s"
