#!/usr/bin/env bash
# tests/integ/farmd_sims.sh - the farm printing for real on a mixed farm:
# slimfarmd with two simulated Marlin printers (one behind TCP, one on a
# pty), an OctoPrint, a Klipper behind Moonraker and a Prusa behind
# PrusaLink simulator (PLA and PETG; 0.4 and 0.6 mm nozzles; five bed
# sizes), 13 jobs (14 with OctoPrint) that all complete (one of them two copies), and on the
# way: the bed-cleared flow (mk3 has no ejector), pause and resume of a
# printer mid-print, a cancel mid-print, and a job that fits no printer
# staying queued with the reason.  At the end each printer's executed log
# must equal the stored G-code of the prints it ran, in order
# (check_farm_logs for Marlin, check_net_logs for the network printers).
# Each network printer is unreachable (503) across the end of the first job
# that reaches line 100 (--fault outage=100): the daemon lets go of the job,
# and when the printer answers again it learns from the printer that the
# print completed (OctoPrint's /api/job, Klipper's print_stats, PrusaLink's
# FINISHED job), re-attaches and the job ends done.
#
# Jobs are prepared in parallel and start in whatever order they become
# ready, so no check assumes submission order: the paused job is whichever
# job mini is printing, the cancelled one a long mini job not paused, and the
# job waiting for mk3's bed to be cleared is whichever mk3 job did not print
# first.  Every wait
# polls for its condition with a bound generous enough for a loaded machine.
# Without an OctoPrint simulator in this build, its printer is left out.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)

start_sim mk3 --speed 3000 --tcp 0
start_sim mini --speed 3000
octo=
"$S" octoprint --help > /dev/null 2>&1 && octo=octo
[ -n "$octo" ] && start_net octo octoprint --speed 3000 --api-key octo-key --fault outage=100
start_net voron moonraker --speed 3000 --api-key voron-key --fault outage=100
start_net mk4 prusalink --speed 3000 --api-key mk4-key --fault outage=100
cp -r config/printers config/materials "$tmp/"
printer() { # NAME MATERIAL NOZZLE BED AUTO_EJECT
  printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\nmaterial: %s\nnozzle_mm: %s\nbed_size: %s\nauto_eject: %s\n' \
    "$1" "$(cat "$tmp/$1.addr")" "$2" "$3" "$4" "$5"
}
netprinter() { # NAME DRIVER KEY MATERIAL NOZZLE BED
  printf '[printer %s]\ndriver: %s\nurl: %s\napi_key: %s\nmaterial: %s\nnozzle_mm: %s\nbed_size: %s\nauto_eject: true\n' \
    "$1" "$2" "$(cat "$tmp/$1.addr")" "$3" "$4" "$5" "$6"
}
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printer mk3 PLA 0.4 "250, 210, 210" false
  printer mini PLA 0.4 "180, 180, 180" true
  [ -n "$octo" ] && netprinter octo octoprint octo-key PETG 0.4 "220, 220, 250"
  netprinter voron moonraker voron-key PETG 0.6 "300, 300, 300"
  netprinter mk4 prusalink mk4-key PLA 0.4 "250, 210, 220"
} > "$tmp/farm.ini"
n_extra=0; [ -n "$octo" ] && n_extra=1
n_printers=$((4 + n_extra))
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq $n_printers ]" || fail "printers: $("$C" printers)"

for s in 8 10 12 14 16 18 20; do tetra "$tmp/t$s.stl" "$s"; done
"$C" shapes "$tmp" > /dev/null || fail "shapes"
# mini's two jobs are long enough to catch mid-print: the first it starts is
# (usually) paused and resumed, the other cancelled.
j_mini1=$(submit "$tmp/lbracket.stl" --material PLA --printer mini --method none)
j_mini2=$(submit "$tmp/frame.stl" --material PLA --printer mini --method none)
j_mk3a=$(submit "$tmp/t10.stl" --material PLA --printer mk3 --method none)
j_mk3b=$(submit "$tmp/t12.stl" --material PLA --printer mk3 --method none)
j_copies=$(submit "$tmp/t8.stl" --material PLA --copies 2 --method none)
j_big=$(submit "$tmp/t16.stl" --material PETG --printer voron --method none)
j_mk4=$(submit "$tmp/t14.stl" --material PLA --printer mk4 --method none)
j_nofit=$(submit "$tmp/t10.stl" --material TPU --method none)
done_jobs="$j_mk3a $j_mk3b $j_copies $j_big $j_mk4"
[ -n "$octo" ] && done_jobs="$done_jobs $(submit "$tmp/t18.stl" --material PETG --printer octo --method none)"
for s in 8 10 12 14 16 18 20; do
  m=PETG; [ $((s % 4)) -eq 0 ] && m=PLA
  done_jobs="$done_jobs $(submit "$tmp/t$s.stl" --material $m --method none)"
done
[ "$(echo $done_jobs | wc -w)" -eq $((12 + n_extra)) ] || fail "$((12 + n_extra)) jobs wanted: $done_jobs"

# job_on PRINTER: the id of the job printing (or paused) on PRINTER, if any.
job_on() {
  api_jobs | json "' '.join(str(j['id']) for j in d['jobs'] if j['printer'] == '$1' and j['state'] in ('printing', 'paused'))"
}

# pause mini mid-print (whichever of its two long jobs came first); nothing
# moves while paused; resume
wait_for 180 sh -c "'$C' printers | grep -qE '^mini +printing .* [1-9][0-9]?%'" || fail "mini never printed: $("$C" printers)"
out=$("$C" pause mini) || fail "pause: $out"
j_paused=$(job_on mini)
[ -n "$j_paused" ] || fail "no job on mini after the pause: $("$C" jobs)"
j_cancel=
for j in $j_mini2 $j_mini1; do
  [ -z "$j_cancel" ] && [ "$j" != "$j_paused" ] && [ "$(job_state "$j")" != done ] && j_cancel=$j
done
# mini may have finished its other long job before the pause caught one: then
# the job to cancel is a third, submitted now (and the count of done jobs holds)
[ -n "$j_cancel" ] || j_cancel=$(submit "$tmp/frame.stl" --material PLA --printer mini --method none)
for j in $j_mini1 $j_mini2 $j_paused; do
  case " $done_jobs $j_cancel " in *" $j "*) ;; *) done_jobs="$done_jobs $j" ;; esac
done
[ "$(job_state "$j_paused")" = paused ] || fail "job $j_paused not paused: $(job_state "$j_paused")"
sleep 1
a1=$(api /api/printers/mini | json 'd["printer"]["progress"]')
sleep 1
a2=$(api /api/printers/mini | json 'd["printer"]["progress"]')
[ "$a1" = "$a2" ] || fail "progress moved while paused: $a1 -> $a2"
out=$("$C" resume mini) || fail "resume: $out"
[ "$(job_state "$j_paused")" = printing ] || fail "job $j_paused not printing after resume"

# cancel the other long mini job once it prints (after the resumed one)
wait_for 180 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j_cancel | /usr/bin/python3 -c 'import json,sys; j=json.load(sys.stdin)[\"job\"]; print(j[\"state\"], j[\"lines_acked\"] > 0)')\" = 'printing True' ]" ||
  fail "job $j_cancel never printed: $("$C" jobs)"
out=$("$C" cancel "$j_cancel") || fail "cancel: $out"
[ "$out" = "job $j_cancel: cancelled" ] || fail "cancel said: $out"

# bed-cleared flow: mk3 finishes its first job and waits; an mk3 job it did
# not print (it prints one at a time, so at least one is left) becomes ready
# and waits for the clear, saying so
wait_for 180 sh -c "'$C' printers | grep -qE '^mk3 +awaiting-clear'" || fail "mk3 never awaited clear: $("$C" printers)"
j_wait=
mk3_job_waits() {
  local j
  for j in $j_mk3a $j_mk3b; do
    [ "$(job_state "$j")" = ready ] && "$C" jobs | grep -qE "^$j .*mk3 is awaiting-clear" && { j_wait=$j; return 0; }
  done
  return 1
}
wait_for 120 mk3_job_waits || fail "no mk3 job waits for the clear: $("$C" jobs)"
sleep 0.5
"$C" printers | grep -qE '^mk3 +awaiting-clear' || fail "mk3 started a job on an uncleared bed"
[ "$(job_state "$j_wait")" = ready ] || fail "job $j_wait: $(job_state "$j_wait"), wanted ready"
out=$("$C" cleared mk3) || fail "cleared: $out"

# mk3 keeps needing a clear after each print: clear it whenever it waits
all_done() {
  "$C" printers | grep -qE '^mk3 +awaiting-clear' && "$C" cleared mk3 > /dev/null
  for j in $done_jobs; do [ "$(job_state "$j")" = done ] || return 1; done
}
wait_for 300 all_done || fail "not all done: $("$C" jobs)"
[ "$(api "/api/jobs/$j_copies" | json 'd["job"]["copies_done"]')" = 2 ] || fail "copies"
[ "$(job_state "$j_cancel")" = cancelled ] || fail "cancelled job: $(job_state "$j_cancel")"
"$C" jobs | grep -qE "^$j_nofit +queued .*fits no printer.*material TPU not loaded" ||
  fail "no-fit job: $("$C" jobs | grep "^$j_nofit ")"
api "/api/jobs/$j_big" | json 'd["prints"][0]["printer"]' | grep -qx voron || fail "voron's job printed elsewhere"

# each network printer's print that ended while it was unreachable was re-attached
for p in voron mk4 $octo; do
  grep -qE "printer\[$p\]: job [0-9]+ re-attached" "$tmp/log" || fail "$p: no job re-attached after its outage"
done

# each printer printed something, and its log is exactly its prints' G-code
sleep 0.5
stop_sims
[ "$(api_jobs | /usr/bin/python3 -c "import json,sys; print(sum(1 for j in json.load(sys.stdin)['jobs'] if j['state']=='done'))")" -ge 13 ] || fail "done count"
# every printer, network ones included, finished at least one print (each has a job pinned)
for p in mk3 mini voron mk4 $octo; do
  n=0
  for j in $(api_jobs | json '" ".join(str(x["id"]) for x in d["jobs"])'); do
    n=$((n + $(api "/api/jobs/$j" | json "sum(1 for p in d['prints'] if p['printer'] == '$p' and p['outcome'] == 'done')")))
  done
  [ "$n" -ge 1 ] || fail "$p finished no print: $("$C" jobs)"
done
check_farm_logs mk3 mini || fail "executed logs differ from the jobs' G-code (Marlin)"
check_net_logs voron mk4 $octo || fail "executed logs differ from the jobs' G-code (network)"
kill -TERM $pid; wait $pid; pid=
echo "farmd_sims: ok ($(echo $done_jobs | wc -w) jobs done on $n_printers printers${octo:+ (OctoPrint included)} in $(( $(date +%s) - t0 )) s)"
