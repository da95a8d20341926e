#!/usr/bin/env bash
# tests/integ/farmd_netctl.sh - manual commands and the time left, through
# slimfarmd's REST API and `slimfarm`, on one printer of each kind the farm
# drives over a console: a simulated Marlin (pty), OctoPrint, Klipper
# behind Moonraker, and a Prusa behind PrusaLink.
#  - `slimfarm command PRINTER G-CODE` (POST /api/printers/NAME/command)
#    reaches the printer: the command is in the simulated printer's
#    executed-command log, for Marlin, OctoPrint and Moonraker; PrusaLink's
#    API has no console, so its printer refuses plainly (501); a printer
#    printing a job refuses (409); a bad body is a 400, an unknown printer
#    a 404; a network printer that no longer answers (its simulator gone,
#    the farm holds it offline) refuses commands and actions with 503;
#  - mid-print, GET /api/printers, GET /api/jobs/ID and `slimfarm printers`
#    give the time left and whose estimate it is: the printer's own for
#    the three network printers (OctoPrint's printTimeLeft, PrusaLink's
#    time_remaining from the file's M73 R, whole minutes; Moonraker's by
#    Mainsail's rule), the farm's from the G-code for Marlin.
# Every wait polls its condition with a bound generous for a loaded machine.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)

start_sim mar --speed 150
start_net octo octoprint --speed 150 --api-key octo-key
start_net klip moonraker --speed 150 --api-key klip-key
start_net prusa prusalink --speed 150 --api-key prusa-key
cp -r config/printers config/materials "$tmp/"
net() { # NAME DRIVER KEY
  printf '[printer %s]\ndriver: %s\nurl: %s\napi_key: %s\npoll_ms: 300\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\nauto_eject: true\n' \
    "$1" "$2" "$(cat "$tmp/$1.addr")" "$3"
}
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer mar]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\nauto_eject: true\n' \
    "$(cat "$tmp/mar.addr")"
  net octo octoprint octo-key
  net klip moonraker klip-key
  net prusa prusalink prusa-key
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -cE '^(mar|octo|klip|prusa) +idle ') -eq 4 ]" ||
  fail "printers: $("$C" printers)"

# ---- manual commands on idle printers ----
for p in mar octo klip; do
  out=$("$C" command $p M117 sf-manual-$p) || fail "command $p: $out"
  [ "$out" = "printer $p: sent 'M117 sf-manual-$p'" ] || fail "command $p said: $out"
done
out=$("$C" command klip "G4 P1 ; a comment") || fail "command klip G4: $out"
[ "$out" = "printer klip: sent 'G4 P1'" ] || fail "command klip G4 said: $out"
# PrusaLink: a plain refusal, 501
out=$("$C" command prusa M117 x 2>&1) && fail "prusa took a command: $out"
echo "$out" | grep -q "501: printer 'prusa': PrusaLink has no endpoint for a console command" ||
  fail "prusa's refusal: $out"
# bad bodies and names
code() { curl -s -o "$tmp/resp" -w '%{http_code}' -H "X-Api-Key: $RW" -H 'Content-Type: application/json' -X POST --data "$2" "$SLIMFARM_URL/api/printers/$1/command"; }
[ "$(code mar '{"command": ""}')" = 400 ] || fail "empty command: $(cat "$tmp/resp")"
[ "$(code mar '{"command": "; only a comment"}')" = 400 ] || fail "comment only: $(cat "$tmp/resp")"
[ "$(code mar '{"command": "G28\nG1 X1"}')" = 400 ] || fail "two lines: $(cat "$tmp/resp")"
grep -q 'not printable ASCII' "$tmp/resp" || fail "two lines said: $(cat "$tmp/resp")"
[ "$(code mar '{"command": "G28", "extra": 1}')" = 400 ] || fail "extra field: $(cat "$tmp/resp")"
[ "$(code nosuch '{"command": "G28"}')" = 404 ] || fail "unknown printer: $(cat "$tmp/resp")"
out=$("$C" command 2>&1); [ $? -eq 2 ] || fail "usage exit: $out"

# ---- mid-print: the time left, and no commands ----
"$C" shapes "$tmp" > /dev/null || fail "shapes"
declare -A job
for p in mar octo klip prusa; do job[$p]=$(submit "$tmp/frame.stl" --material PLA --printer $p --method none); done
left() { api "/api/printers/$1" | json '"%s %s" % (d["printer"]["time_left_from"], d["printer"]["time_left_s"])'; }
mid() { # PRINTER WHOSE: printing with lines acked and a time left from WHOSE
  [ "$(api "/api/jobs/${job[$1]}" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ] || return 1
  set -- $(left "$1") "$2"
  [ "$1" = "$3" ] && [ "$2" -gt 0 ] 2>/dev/null
}
wait_for 300 mid mar farm || fail "mar: no farm estimate mid-print: $(left mar); $("$C" printers)"
wait_for 300 mid octo printer || fail "octo: no printer estimate mid-print: $(left octo); $("$C" printers)"
wait_for 300 mid klip printer || fail "klip: no printer estimate mid-print: $(left klip); $("$C" printers)"
wait_for 300 mid prusa printer || fail "prusa: no printer estimate mid-print: $(left prusa); $("$C" printers)"
# PrusaLink's is the file's M73 R: whole minutes
set -- $(left prusa)
[ "$1" != printer ] || [ $(($2 % 60)) -eq 0 ] || fail "prusa's time left $2 s is not M73's minutes"
# the job's view says it too
[ "$(api "/api/jobs/${job[octo]}" | json 'd["job"].get("time_left_from")')" = printer ] ||
  fail "job view: $(api "/api/jobs/${job[octo]}")"
# `slimfarm printers` shows whose
"$C" printers | grep -E '^mar ' | grep -q '(farm)' || fail "printers (mar): $("$C" printers)"
"$C" printers | grep -E '^klip ' | grep -qE '[0-9]+[hm][0-9]+[ms] \(printer\)' || fail "printers (klip): $("$C" printers)"
# a printer printing takes no manual command
out=$("$C" command mar G28 2>&1) && fail "mar took a command mid-print: $out"
echo "$out" | grep -q "409: printer mar is printing job ${job[mar]}" || fail "mar's refusal: $out"
out=$("$C" command klip G28 2>&1) && fail "klip took a command mid-print: $out"
echo "$out" | grep -q "409: " || fail "klip's refusal: $out"

all_done() { for p in mar octo klip prusa; do [ "$(job_state "${job[$p]}")" = done ] || return 1; done; }
wait_for 600 all_done || fail "not all done: $("$C" jobs)"
[ "$(left klip)" = "None None" ] || fail "klip keeps a time left after its job: $(left klip)"

# each command ran on its printer (the executed logs are written at exit)
stop_sims
for p in mar octo klip; do
  grep -qx "M117 sf-manual-$p" "$tmp/$p.log" || fail "$p's log lacks the manual command"
done
grep -qx "G4 P1" "$tmp/klip.log" || fail "klip's log lacks G4 P1"
grep -q "sf-manual" "$tmp/prusa.log" && fail "prusa ran a command it refused"
# the simulators are gone: once offline, a network printer is unreachable (503)
offline() { "$C" printers | grep -qE "^$1 +offline "; }
for p in klip prusa; do
  wait_for 120 offline $p || fail "$p never went offline: $("$C" printers)"
done
out=$("$C" command klip M117 x 2>&1) && fail "klip took a command offline: $out"
echo "$out" | grep -q "503: printer klip is offline" || fail "klip offline: $out"
out=$("$C" pause prusa 2>&1) && fail "prusa paused offline: $out"
echo "$out" | grep -q "503: printer prusa is offline" || fail "prusa offline: $out"
kill -TERM $pid; wait $pid; pid=
echo "farmd_netctl: ok ($(( $(date +%s) - t0 )) s)"
