#!/usr/bin/env bash
# tests/integ/farmd_policy_start.sh - a stored job is judged again by the
# G-code policy of the printer it starts on (issue 29), through the REST
# API against a simulated Marlin: a file with M600 uploaded while the
# printer is attended waits behind a long job; farm.ini then makes the
# printer unattended (SIGHUP).  When the printer frees, the M600 job must
# not reach it: it fails at its start naming the file, line and command,
# is not retried, no line of it runs on the printer (the simulator's log
# of executed commands), and the printer stays idle and prints the next
# clean job.
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

# upload FILE NAME: POST /api/files/local as PrusaSlicer does; print the HTTP status,
# the reply in $tmp/r
upload() {
  curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -F print=true -F path= \
    -F "file=@$1;filename=$2" "$SLIMFARM_URL/api/files/local"
}
upload_job() { # FILE NAME: the new job's id
  local c; c=$(upload "$1" "$2")
  [ "$c" = 201 ] || fail "upload $2: $c $(cat "$tmp/r")"
  json 'd["slimfarm"]["job_id"]' < "$tmp/r"
}
state_is() { [ "$(job_state "$1")" = "$2" ]; }

# a: a long job holds the printer (one dwell a second, simulated in real time)
{ printf 'G90\nM83\n'; for _ in $(seq 600); do printf 'G4 S1\n'; done; } > "$tmp/long.gcode"
a=$(upload_job "$tmp/long.gcode" long.gcode)
wait_for 60 state_is "$a" printing || fail "job $a is $(job_state "$a")"

# b: M600 on line 5, accepted while mk3 is attended; it waits for mk3
printf 'G90\nM83\nG1 X77.7 Y77.7 F6000\nG1 X78.8 Y78.8 E0.5 F1800\nM600\nG1 X79.9 Y79.9 E0.5\nM84\n' \
  > "$tmp/change.gcode"
b=$(upload_job "$tmp/change.gcode" change.gcode)
state_is "$b" ready || fail "job $b is $(job_state "$b")"

# mk3 is no longer attended
write_config false
kill -HUP "$pid"
wait_for 30 grep -q "reloaded " "$tmp/log" || fail "no reload"
"$C" cancel "$a" > /dev/null || fail "cancel $a"

# b fails at its start, naming the line, not retried; mk3 is idle
wait_for 60 state_is "$b" failed || fail "job $b is $(job_state "$b"): $("$C" printers)"
reason=$(api "/api/jobs/$b" | json 'd["job"]["reason"]')
[[ "$reason" == *"G-code 'change.gcode': line 5: M600: a filament change waits for a person"* ]] ||
  fail "job $b: reason: $reason"
echo "b: job $b failed: $reason"
wait_for 30 sh -c "'$C' printers | grep -qE '^mk3 +idle'" || fail "mk3: $("$C" printers)"

# c: a clean job prints to the end on it; b's lines never ran
printf 'G90\nM83\nG1 X11.1 Y11.1 F6000\nG1 X12.2 Y12.2 E0.5 F1800\nM84\n' > "$tmp/clean.gcode"
c=$(upload_job "$tmp/clean.gcode" clean.gcode)
wait_for 60 state_is "$c" done || fail "job $c is $(job_state "$c"): $("$C" printers)"
state_is "$b" failed || fail "job $b is $(job_state "$b") (retried?)"
stop_sims
grep -q '^G1 X11.1 Y11.1 F6000' "$tmp/mk3.log" || fail "job $c's lines are not in mk3's log"
if grep -nE '^(M600|G1 X7[789]\.[789] )' "$tmp/mk3.log"; then fail "job $b reached the printer"; fi
echo "ok"
