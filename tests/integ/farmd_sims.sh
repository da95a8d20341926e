#!/usr/bin/env bash
# tests/integ/farmd_sims.sh - the farm printing for real: slimfarmd with four
# simulated Marlin printers (two on ptys, two behind TCP; PLA and PETG; 0.4
# and 0.6 mm nozzles; four bed sizes), 12 jobs that all complete (one of
# them two copies), and on the way: the bed-cleared flow (mk3 has no
# ejector), pause and resume of a printer mid-print, a cancel mid-print, and
# a job that fits no printer staying queued with the reason.  At the end
# each printer's executed log must equal the stored G-code of the prints
# it ran, in order (check_farm_logs in lib/farm.sh).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
t0=$(date +%s)

start_sim mk3 --speed 3000
start_sim mini --speed 3000
start_sim ender --speed 3000 --tcp 0
start_sim big --speed 3000 --tcp 0
cp -r config/printers config/materials "$tmp/"
printer() { # NAME MATERIAL NOZZLE BED AUTO_EJECT
  printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: %s\nnozzle_mm: %s\nbed_size: %s\nauto_eject: %s\n' \
    "$1" "$(cat "$tmp/$1.addr")" "$2" "$3" "$4" "$5"
}
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printer mk3 PLA 0.4 "250, 210, 210" false
  printer mini PLA 0.4 "180, 180, 180" true
  printer ender PETG 0.4 "220, 220, 250" true
  printer big PETG 0.6 "300, 300, 300" true
} > "$tmp/farm.ini"
start_daemon
wait_for 20 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 4 ]" || fail "printers: $("$C" printers)"

for s in 8 10 12 14 16 18 20; do tetra "$tmp/t$s.stl" "$s"; done
"$C" shapes "$tmp" > /dev/null || fail "shapes"
# The paused and the cancelled job are long enough to catch mid-print.
j_pause=$(submit "$tmp/lbracket.stl" --material PLA --printer mini --method none)
j_cancel=$(submit "$tmp/frame.stl" --material PLA --printer mini --method none)
j_mk3a=$(submit "$tmp/t10.stl" --material PLA --printer mk3 --method none)
j_mk3b=$(submit "$tmp/t12.stl" --material PLA --printer mk3 --method none)
j_copies=$(submit "$tmp/t8.stl" --material PLA --copies 2 --method none)
j_big=$(submit "$tmp/t16.stl" --material PETG --printer big --method none)
j_nofit=$(submit "$tmp/t10.stl" --material TPU --method none)
done_jobs="$j_pause $j_mk3a $j_mk3b $j_copies $j_big"
for s in 8 10 12 14 16 18 20; do
  m=PETG; [ $((s % 4)) -eq 0 ] && m=PLA
  done_jobs="$done_jobs $(submit "$tmp/t$s.stl" --material $m --method none)"
done
[ "$(echo $done_jobs | wc -w)" -eq 12 ] || fail "12 jobs wanted: $done_jobs"

# pause mini mid-print; nothing moves while paused; resume
wait_for 60 sh -c "'$C' printers | grep -qE '^mini +printing .* [1-9][0-9]?%'" || fail "mini never printed: $("$C" printers)"
out=$("$C" pause mini) || fail "pause: $out"
[ "$(job_state "$j_pause")" = paused ] || fail "job $j_pause not paused: $(job_state "$j_pause")"
sleep 1
a1=$(api /api/printers/mini | json 'd["printer"]["progress"]')
sleep 1
a2=$(api /api/printers/mini | json 'd["printer"]["progress"]')
[ "$a1" = "$a2" ] || fail "progress moved while paused: $a1 -> $a2"
out=$("$C" resume mini) || fail "resume: $out"
[ "$(job_state "$j_pause")" = printing ] || fail "job $j_pause not printing after resume"

# bed-cleared flow: mk3 finishes its first job and waits; the second waits for it
wait_for 90 sh -c "'$C' printers | grep -qE '^mk3 +awaiting-clear'" || fail "mk3 never awaited clear: $("$C" printers)"
sleep 0.5
"$C" printers | grep -qE '^mk3 +awaiting-clear' || fail "mk3 started a job on an uncleared bed"
[ "$(job_state "$j_mk3b")" = ready ] || fail "job $j_mk3b: $(job_state "$j_mk3b"), wanted ready"
"$C" jobs | grep -qE "^$j_mk3b .*mk3 is awaiting-clear" || fail "no reason for $j_mk3b: $("$C" jobs)"
out=$("$C" cleared mk3) || fail "cleared: $out"

# cancel the frame job once it prints on mini
wait_for 120 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_cancel | /usr/bin/python3 -c 'import json,sys; j=json.load(sys.stdin)[\"job\"]; print(j[\"state\"], j[\"lines_acked\"] > 0)')\" = 'printing True' ]" ||
  fail "job $j_cancel never printed: $("$C" jobs)"
out=$("$C" cancel "$j_cancel") || fail "cancel: $out"
[ "$out" = "job $j_cancel: cancelled" ] || fail "cancel said: $out"

# mk3 keeps needing a clear after each print: clear it whenever it waits
all_done() {
  "$C" printers | grep -qE '^mk3 +awaiting-clear' && "$C" cleared mk3 > /dev/null
  for j in $done_jobs; do [ "$(job_state "$j")" = done ] || return 1; done
}
wait_for 150 all_done || fail "not all done: $("$C" jobs)"
[ "$(api "/api/jobs/$j_copies" | json 'd["job"]["copies_done"]')" = 2 ] || fail "copies"
[ "$(job_state "$j_cancel")" = cancelled ] || fail "cancelled job: $(job_state "$j_cancel")"
"$C" jobs | grep -qE "^$j_nofit +queued .*fits no printer.*material TPU not loaded" ||
  fail "no-fit job: $("$C" jobs | grep "^$j_nofit ")"
api "/api/jobs/$j_big" | json 'd["prints"][0]["printer"]' | grep -qx big || fail "big job printed elsewhere"

# each printer printed something, and its log is exactly its prints' G-code
sleep 0.5
stop_sims
for p in mk3 mini ender big; do
  [ "$(api /api/jobs | /usr/bin/python3 -c "import json,sys; print(sum(1 for j in json.load(sys.stdin)['jobs'] if j['state']=='done'))")" -ge 12 ] || fail "done count"
done
check_farm_logs mk3 mini ender big || fail "executed logs differ from the jobs' G-code"
kill -TERM $pid; wait $pid; pid=
echo "farmd_sims: ok (12 jobs on 4 printers in $(( $(date +%s) - t0 )) s)"
