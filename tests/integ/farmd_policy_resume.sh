#!/usr/bin/env bash
# tests/integ/farmd_policy_resume.sh - a resumed job is judged again by the
# G-code policy of its printer as it is then (issue 29), as a start is
# (farmd_policy_start.sh): a file with M600 near its end prints on an
# attended Marlin simulator; the daemon is killed mid-print and comes back
# with the printer unattended; the operator's resume must fail the job,
# naming the file, line and command, and its M600 must never reach the
# printer (the simulator's log of executed commands).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"

start_sim mk3 --speed 1
write_config() { # ATTENDED
  one_printer_ini mk3 true
  printf 'material: PLA\ngcode_models: *\nattended: %s\n' "$1" >> "$tmp/farm.ini"
}
write_config true
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^mk3 +idle'" || fail "printer: $("$C" printers)"

# one dwell a second (simulated in real time), then M600 on line 64
{ printf 'G90\nM83\n'; for _ in $(seq 60); do printf 'G4 S1\n'; done
  printf 'G1 X77.7 Y77.7 F6000\nM600\nG1 X79.9 Y79.9 E0.5\nM84\n'; } > "$tmp/change.gcode"
code=$(curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -F print=true -F path= \
  -F "file=@$tmp/change.gcode;filename=change.gcode" "$SLIMFARM_URL/api/files/local")
[ "$code" = 201 ] || fail "upload: $code $(cat "$tmp/r")"
j=$(json 'd["slimfarm"]["job_id"]' < "$tmp/r")
wait_for 60 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j | grep -o '\"state\":\"printing\"')\" ]" ||
  fail "job $j is $(job_state "$j")"

# killed mid-print; back with mk3 unattended
kill -9 "$pid"; wait "$pid" 2>/dev/null; pid=
write_config false
start_daemon
[ "$(job_state "$j")" = interrupted ] || fail "job $j is $(job_state "$j")"
wait_for 30 sh -c "'$C' printers | grep -qE '^mk3 +idle'" || fail "mk3 not back: $("$C" printers)"

# the resume (from line 3, whatever was acknowledged) is refused at its check
code=$(curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -H 'Content-Type: application/json' \
  -d '{"line": 3}' "$SLIMFARM_URL/api/jobs/$j/resume")
[ "$code" = 200 ] || [ "$code" = 202 ] || fail "resume: $code $(cat "$tmp/r")"
wait_for 60 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j | grep -o '\"state\":\"failed\"')\" ]" ||
  fail "job $j is $(job_state "$j"): $("$C" printers)"
reason=$(api "/api/jobs/$j" | json 'd["job"]["reason"]')
[[ "$reason" == *"G-code 'change.gcode': line 64: M600: a filament change waits for a person"* ]] ||
  fail "job $j: reason: $reason"
echo "job $j failed at its resume: $reason"
stop_sims
if grep -nE '^(M600|G1 X79\.9 )' "$tmp/mk3.log"; then fail "the resumed job's M600 reached the printer"; fi
echo "ok"
