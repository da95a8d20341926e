#!/usr/bin/env bash
# tests/integ/farmd_safety.sh - issue 29's cases 2, 3, 6 and 7 through the
# REST API against simulated Marlins, and the operator's emergency stop:
#   2  a manual "M110 N1000" is refused (400) and the printer prints its
#      next job to the end (it used to hang at 0 lines);
#   3  manual commands are refused (409) on a printer awaiting clear, one
#      holding an interrupted job and one in error; taken (and logged with
#      the sender's key label) on an idle one with a clear bed;
#   6  slimfarmd killed mid-print, a printer behind TCP (no reset on
#      reconnect) comes back hot with no print: after hold_heat_min its
#      heaters are off (M104 S0, M140 S0 in its executed log; said in its
#      message and the event log); a resume heats again;
#   e  the emergency stop: M112 reaches the printer, the printer is in
#      error and the job on it failed although it had a retry left;
#   e' Moonraker's emergency stop is its /printer/emergency_stop (Klippy
#      shut down), the printer in error, the job failed;
#   7  a printer answering M105 with a plain "ok" fails its job within
#      seconds, saying what it answered (it used to crawl a line a second).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"

start_sim m --tcp 0 --speed 20
# k without ADVANCED_OK: its oks carry no line number, so a plain ok to M105 passes for a line's
"$S" marlin --baud 1000000 --log "$tmp/k.log" --fault okt=plain --speed 20 > "$tmp/k.out" 2> "$tmp/k.err" &
sims+=($!)
wait_for 30 test -s "$tmp/k.out" || fail "sim k did not start"
echo "pty:$(head -n 1 "$tmp/k.out")" > "$tmp/k.addr"
start_net klip moonraker --speed 5 --api-key klip-key
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer m]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\nhold_heat_min: 0.05\n' \
    "$(cat "$tmp/m.addr")"
  printf '[printer k]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: PLA\n' "$(cat "$tmp/k.addr")"
  printf '[printer klip]\ndriver: moonraker\nurl: %s\napi_key: klip-key\npoll_ms: 300\nmaterial: PLA\n' \
    "$(cat "$tmp/klip.addr")"
} > "$tmp/farm.ini"
start_daemon
wait_for 30 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 3 ]" || fail "printers: $("$C" printers)"
tetra "$tmp/t.stl" 12

# cmd PRINTER GCODE: POST a manual command, print the HTTP status.
cmd() {
  curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -H 'Content-Type: application/json' \
    -d "{\"command\": \"$2\"}" "$SLIMFARM_URL/api/printers/$1/command"
}
pfield() { api "/api/printers/$1" | json "d['printer']$2"; }

# 2: M110 (and M111) from the console never reach the link
c=$(cmd m 'M110 N1000'); [ "$c" = 400 ] || fail "2: M110 N1000: $c $(cat "$tmp/r")"
c=$(cmd m 'M111 S7'); [ "$c" = 400 ] || fail "2: M111 S7: $c $(cat "$tmp/r")"
echo "2: M110 N1000 -> $c $(cat "$tmp/r")"
a=$(submit "$tmp/t.stl" --printer m --method none)
wait_for 180 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$a | grep -o '\"state\":\"done\"')\" ]" ||
  fail "2: job $a after M110: $(job_state "$a"): $("$C" printers)"

# 3: not on a bed that holds a part
[ "$(pfield m "['state']")" = awaiting-clear ] || fail "3: m is $(pfield m "['state']")"
c=$(cmd m 'G1 Z0.2 F600'); [ "$c" = 409 ] || fail "3: awaiting-clear: $c $(cat "$tmp/r")"
echo "3: awaiting-clear -> $c $(cat "$tmp/r")"
"$C" cleared m > /dev/null || fail "cleared m"
c=$(cmd m 'G28'); [ "$c" = 200 ] || fail "3: idle: $c $(cat "$tmp/r")"
wait_for 5 grep -qE "printer\[m\]: manual command from key [0-9a-f]{8}: G28" "$tmp/log" ||
  fail "3: the manual command is not logged with its key"

# 6: killed mid-print; the TCP printer comes back hot with no print
b=$(submit "$tmp/t.stl" --printer m --method none --retries 1)
hot_printing() { [ "$(job_state "$b")" = printing ] && [ "$(pfield m "['temps']['nozzle_target_c'] > 0 and d['printer']['job_id'] > 0")" = True ]; }
wait_for 120 hot_printing || fail "6: job $b never printed hot: $("$C" printers)"
sleep 1
kill -9 "$pid"; wait "$pid" 2>/dev/null; pid=
start_daemon
[ "$(job_state "$b")" = interrupted ] || fail "6: job $b is $(job_state "$b")"
wait_for 20 sh -c "'$C' printers | grep -qE '^m +idle'" || fail "6: m not back: $("$C" printers)"
c=$(cmd m 'G1 Z0.2 F600'); [ "$c" = 409 ] || fail "3: interrupted job: $c $(cat "$tmp/r")"
echo "3: interrupted job -> $c $(cat "$tmp/r")"
wait_for 30 sh -c "curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/printers/m | grep -q 'heaters off'" ||
  fail "6: heaters not turned off: $(api /api/printers/m)"
grep -q '^M104 S0' "$tmp/m.log" && grep -q '^M140 S0' "$tmp/m.log" || fail "6: no M104/M140 S0 in m's log"
grep -q "heaters off" "$tmp/log" || fail "6: not logged"
echo "6: $(pfield m "['message']")"
wait_for 10 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/printers/m | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"printer\"][\"temps\"][\"nozzle_target_c\"])')\" = 0.0 ]" ||
  fail "6: nozzle target not 0: $(api /api/printers/m)"
# a resume heats again (the resume preamble's M104/M109 after the M104 S0)
off_at=$(grep -n '^M104 S0' "$tmp/m.log" | tail -n 1 | cut -d: -f1)
"$C" resume-job "$b" > /dev/null || fail "6: resume $b"
wait_for 60 sh -c "tail -n +$off_at '$tmp/m.log' | grep -qE '^M10[49] S[1-9]'" || fail "6: the resume did not heat"

# e: the emergency stop of a printing printer: error, the job failed with its retry unspent
wait_for 60 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$b | grep -o '\"state\":\"printing\"')\" ]" ||
  fail "e: job $b not printing: $(job_state "$b")"
"$C" emergency-stop m > "$tmp/estop.out" 2>&1 || fail "e: emergency-stop: $(cat "$tmp/estop.out")"
[ "$(pfield m "['state']")" = error ] || fail "e: m is $(pfield m "['state']")"
[ "$(job_state "$b")" = failed ] || fail "e: job $b is $(job_state "$b") (retried?)"
halted() { kill -USR1 "$sim_m"; sleep 0.2; grep -q 'halted=1' "$tmp/m.err"; }
wait_for 5 halted || fail "e: the printer did not halt: $(tail -2 "$tmp/m.err")"
c=$(cmd m 'G28'); [ "$c" = 409 ] || fail "3: error: $c $(cat "$tmp/r")"
echo "e: $(cat "$tmp/estop.out"); job $b $(job_state "$b"); 3: error -> $c"

# e': Moonraker's emergency stop
kj=$(submit "$tmp/t.stl" --printer klip --method none --retries 1)
wait_for 120 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$kj | grep -o '\"state\":\"printing\"')\" ]" ||
  fail "e': job $kj not printing: $(job_state "$kj")"
"$C" emergency-stop klip > "$tmp/estop.out" 2>&1 || fail "e': emergency-stop klip: $(cat "$tmp/estop.out")"
[ "$(job_state "$kj")" = failed ] || fail "e': job $kj is $(job_state "$kj")"
klippy() { curl -sf -H 'X-Api-Key: klip-key' "$(cat "$tmp/klip.addr")/printer/info" | grep -q '"shutdown"'; }
wait_for 10 klippy || fail "e': Klippy not shut down: $(curl -s -H 'X-Api-Key: klip-key' "$(cat "$tmp/klip.addr")/printer/info")"
[ "$(pfield klip "['state']")" = error ] || fail "e': klip is $(pfield klip "['state']")"
echo "e': $(cat "$tmp/estop.out"); job $kj $(job_state "$kj"); Klippy shut down"

# 7: plain "ok" to M105: the job fails within seconds, saying what came
k=$(submit "$tmp/t.stl" --printer k --method none --retries 0)
wait_for 120 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$k | grep -o '\"state\":\"failed\"')\" ]" ||
  fail "7: job $k is $(job_state "$k"): $("$C" printers)"
reason=$(api "/api/jobs/$k" | json 'd["job"]["reason"]')
[[ "$reason" == *"answered only by 'ok'"* ]] || fail "7: reason: $reason"
echo "7: job $k failed: $reason"
echo "ok"
