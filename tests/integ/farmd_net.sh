#!/usr/bin/env bash
# tests/integ/farmd_net.sh - slimfarmd driving Klipper (Moonraker) and Prusa
# (PrusaLink) printers through their HTTP APIs, against the simulators, as
# it would real ones.  On the way:
#  - jobs on each leave the executed-command log of their G-code, once each,
#    in order (the Marlin path's standard);
#  - pause, resume and cancel through the daemon's REST API (the CLI); the
#    cancel lands while PrusaLink's answer to the upload is still on its way
#    (the print already running): the printer still gets it and runs its
#    cancel script before the next job;
#  - a wrong API key: `slimfarm printers` says authentication failed;
#  - Klipper shuts down mid-job: the printer is in error with Klipper's
#    message, and the job is retried or waiting, never lost;
#  - a PrusaLink printer on HTTP Digest that cuts the first upload half-way
#    and answers 503s: the job still ends done (a print that ends while its
#    printer is unreachable: farmd_sims.sh's outage fault);
#  - kill -9 of slimfarmd mid-print, then a restart: the daemon finds the
#    print still running on the printer (same file name and size), takes
#    it back and the job ends done.
# Every wait polls for its condition with a bound generous for a loaded machine.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)

start_net voron moonraker --speed 2000 --api-key voron-key
# mk4 at a slower pace: its long job (63 min estimated, 25 s here) must outlast the
# 8 s the upload's answer is held plus the cancel's way under load (at 2000x it ran
# ~10 s, and the printer sometimes finished it before the cancel could reach it)
start_net mk4 prusalink --speed 150 --api-key mk4-key --fault slow-upload=8000@2
start_net locked moonraker --speed 2000 --api-key the-right-key
start_net shut moonraker --speed 2000 --fault shutdown=60
start_net flaky prusalink --speed 2000 --user maker --password flaky-pw --fault drop-upload=1 --fault 5xx=3@6
cp -r config/printers config/materials "$tmp/"
printer() { # NAME DRIVER KEY|user:password
  printf '[printer %s]\ndriver: %s\nurl: %s\n' "$1" "$2" "$(cat "$tmp/$1.addr")"
  case "$3" in
  "") ;;
  *:*) printf 'user: %s\npassword: %s\n' "${3%%:*}" "${3#*:}" ;;
  *) printf 'api_key: %s\n' "$3" ;;
  esac
  printf 'material: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\nauto_eject: true\n'
}
write_config() {
  {
    printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
    printer voron moonraker voron-key
    printer mk4 prusalink mk4-key
    printer locked moonraker a-wrong-key
    printer shut moonraker ""
    printer flaky prusalink maker:flaky-pw
  } > "$tmp/farm.ini"
}
write_config
start_daemon
wait_for 60 sh -c "[ \$('$C' printers | grep -cE '^(voron|mk4|shut|flaky) +idle ') -eq 4 ]" ||
  fail "printers: $("$C" printers)"

# a wrong key is an authentication error, said plainly
wait_for 30 sh -c "'$C' printers | grep -E '^locked ' | grep -q 'authentication failed (check api_key)'" ||
  fail "locked: $("$C" printers)"

for s in 10 12 14; do tetra "$tmp/t$s.stl" "$s"; done
"$C" shapes "$tmp" > /dev/null || fail "shapes"
j_v1=$(submit "$tmp/t10.stl" --material PLA --printer voron --method none)
j_vlong=$(submit "$tmp/frame.stl" --material PLA --printer voron --method none)
j_m1=$(submit "$tmp/t12.stl" --material PLA --printer mk4 --method none)
j_mlong=$(submit "$tmp/lbracket.stl" --material PLA --printer mk4 --method none)
j_shut=$(submit "$tmp/t14.stl" --material PLA --printer shut --method none)
j_flaky=$(submit "$tmp/t12.stl" --material PLA --printer flaky --method none)

# job_on PRINTER: the job printing (or paused) on PRINTER, if any.
job_on() {
  api_jobs | json "' '.join(str(j['id']) for j in d['jobs'] if j['printer'] == '$1' and j['state'] in ('printing', 'paused'))"
}

# pause voron's long job once it is under way (the short one may end as the
# pause lands); nothing moves; resume
vlong_printing() {
  [ "$(api "/api/jobs/$j_vlong" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]
}
wait_for 180 vlong_printing || fail "voron never printed job $j_vlong: $("$C" printers); $("$C" jobs)"
out=$("$C" pause voron) || fail "pause: $out"
j_paused=$(job_on voron)
[ "$j_paused" = "$j_vlong" ] || fail "voron pauses job '$j_paused', wanted $j_vlong"
[ "$(job_state "$j_paused")" = paused ] || fail "job $j_paused not paused"
wait_for 20 sh -c "'$C' printers | grep -qE '^voron +paused'" || fail "voron: $("$C" printers)"
sleep 1
a1=$(api /api/printers/voron | json 'd["printer"]["progress"]')
sleep 1
a2=$(api /api/printers/voron | json 'd["printer"]["progress"]')
[ "$a1" = "$a2" ] || fail "progress moved while paused: $a1 -> $a2"
out=$("$C" resume voron) || fail "resume: $out"
[ "$(job_state "$j_paused")" = printing ] || fail "job $j_paused not printing after resume"

# cancel mk4's long job once the printer runs it, while its answer to the
# upload is still on the way (slow-upload: PrusaLink answers a
# Print-After-Upload PUT once it has stored and started the file; mk4's
# first two uploads, j_m1's and j_mlong's in either order, answer late): the
# cancel must still reach the printer, which runs its cancel script before
# the farm sends mk4 its next job (check_net_logs below).  (Cutting the
# upload and calling the job cancelled left the printer printing it whole.)
mlong_on_mk4() { # the printer itself runs j_mlong's file (whatever the farm knows yet)
  local sha; sha=$(api "/api/jobs/$j_mlong" | json 'd["job"]["gcode_sha"] or ""')
  [ -n "$sha" ] && curl -sf -H 'X-Api-Key: mk4-key' "$(cat "$tmp/mk4.addr")/api/v1/job" 2> /dev/null |
    /usr/bin/python3 -c "import json,sys; d=json.load(sys.stdin); sys.exit(0 if '$sha' in d['file']['display_name'] and d['state'] == 'PRINTING' and d['progress'] > 0 else 1)" 2> /dev/null
}
wait_for 180 mlong_on_mk4 || fail "mk4 never ran job $j_mlong: $("$C" jobs)"
out=$("$C" cancel "$j_mlong") || fail "cancel: $out"
[ "$out" = "job $j_mlong: cancelled" ] || fail "cancel said: $out"

# Klipper shut down mid-job: the printer is in error with Klipper's words,
# and the job is retried or waits (never lost, never "done")
wait_for 180 sh -c "'$C' printers | grep -E '^shut ' | grep -q 'error.*MCU .mcu. shutdown: Timer too close'" ||
  fail "shut: $("$C" printers)"
case "$(job_state "$j_shut")" in ready | queued | preparing | failed) ;; *) fail "job $j_shut: $(job_state "$j_shut")" ;; esac

all_done() { for j in "$@"; do [ "$(job_state "$j")" = done ] || return 1; done; }
wait_for 300 all_done $j_v1 $j_vlong $j_m1 $j_flaky || fail "not all done: $("$C" jobs)"
[ "$(job_state "$j_mlong")" = cancelled ] || fail "cancelled job: $(job_state "$j_mlong")"
grep -q 'printer\[flaky\]: upload failed' "$tmp/log" || fail "flaky's cut upload went unnoticed"

# the daemon dies mid-print and comes back: the print is taken back
j_kill=$(submit "$tmp/frame.stl" --material PLA --printer mk4 --method none)
# (the printer's own progress of it: "printing ... N%" in `slimfarm printers` also
# matched "uploading N%", and a kill then left a job the printer never got interrupted)
kill_ready() {
  [ "$(api "/api/jobs/$j_kill" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]
}
wait_for 180 kill_ready || fail "mk4 never printed job $j_kill: $("$C" printers)"
kill -9 $pid; wait $pid 2>/dev/null; pid=
start_daemon
wait_for 300 all_done $j_kill || fail "job $j_kill after the restart: $(job_state "$j_kill"); $("$C" jobs)"
grep -q "job $j_kill re-attached" "$tmp/log" || fail "job $j_kill was not re-attached"

# each printer's log holds its prints' G-code, once each, in order
sleep 0.5
stop_sims
check_net_logs voron mk4 flaky || fail "executed logs differ from the jobs' G-code"
kill -TERM $pid; wait $pid; pid=
echo "farmd_net: ok ($(( $(date +%s) - t0 )) s)"
