#!/usr/bin/env bash
# tests/integ/farmd_mr_history.sh - a Klipper print that ends while
# slimfarmd is down, and a Klipper restart that wipes print_stats before
# the daemon is back: the restarted daemon finds the run in Moonraker's job
# history (GET /server/history/list: same file, started after its upload,
# "completed") and the job ends done, not interrupted.  A second job whose
# run is cancelled at the printer meanwhile is found "cancelled" there: the
# print failed (a cancel at the printer, as when the daemon watches it) and
# the job goes on to its retry instead of waiting interrupted.
# Every wait polls its condition with a bound generous for a loaded machine.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
t0=$(date +%s)

start_net klip moonraker --speed 600
addr=$(cat "$tmp/klip.addr")
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer klip]\ndriver: moonraker\nurl: %s\npoll_ms: 300\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\nauto_eject: true\n' "$addr"
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^klip +idle '" || fail "printers: $("$C" printers)"
"$C" shapes "$tmp" > /dev/null || fail "shapes"

ps_state() { curl -sf "$addr/printer/objects/query?print_stats" | json 'd["result"]["status"]["print_stats"]["state"]'; }
klippy() { curl -sf "$addr/server/info" | json 'd["result"]["klippy_state"]'; }
printing() { [ "$(api "/api/jobs/$1" | json '"%s %s" % (d["job"]["state"], d["job"]["lines_acked"] > 0)')" = "printing True" ]; }

# once for a run that completes, once for one cancelled at the printer
for end in complete cancelled; do
  j=$(submit "$tmp/frame.stl" --material PLA --printer klip --method none)
  wait_for 300 printing "$j" || fail "job $j never printed: $("$C" jobs)"
  kill -9 $pid; wait $pid 2>/dev/null; pid=
  [ $end = cancelled ] && { curl -sf -X POST "$addr/printer/print/cancel" > /dev/null || fail "cancel at the printer"; }
  wait_for 300 sh -c "[ \"\$(curl -sf '$addr/printer/objects/query?print_stats' | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"result\"][\"status\"][\"print_stats\"][\"state\"])')\" = $end ]" ||
    fail "the print did not end $end at the printer: $(ps_state)"
  # Klipper restarts: print_stats forgets the file, the history keeps it
  curl -sf -X POST "$addr/printer/firmware_restart" > /dev/null || fail "firmware_restart"
  wait_for 60 sh -c "[ \"\$(curl -sf '$addr/server/info' | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"result\"][\"klippy_state\"])')\" = ready ]" ||
    fail "klippy not ready: $(klippy)"
  [ "$(ps_state)" = standby ] || fail "print_stats after the restart: $(ps_state)"
  start_daemon
  if [ $end = complete ]; then
    wait_for 120 sh -c "[ \"\$(curl -sf -H 'X-Api-Key: $RW' $SLIMFARM_URL/api/jobs/$j | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[\"job\"][\"state\"])')\" = done ]" ||
      fail "job $j after the restart: $(job_state "$j") (wanted done); $("$C" jobs)"
    grep -q "ended while we were away (Moonraker's job history: completed)" "$tmp/log" ||
      fail "job $j was not found in the history"
  else
    # the run failed (cancelled at the printer) and the job retries: never interrupted
    ran() { api "/api/jobs/$j" | json '" ".join(p["outcome"] for p in d["prints"])'; }
    # (its first print is closed interrupted by the crash recovery, the
    # re-attached one failed, then the retry)
    failed_run() { ran | grep -qw failed; }
    wait_for 120 failed_run || fail "job $j after the restart: $(job_state "$j"), prints: $(ran)"
    grep -q "ended while we were away (Moonraker's job history: cancelled)" "$tmp/log" ||
      fail "job $j was not found in the history"
    case "$(job_state "$j")" in
    ready | printing) "$C" cancel "$j" > /dev/null || fail "cancel $j" ;;
    done) ;;
    *) fail "job $j: $(job_state "$j") after its failed run" ;;
    esac
  fi
  wait_for 120 sh -c "'$C' printers | grep -qE '^klip +idle '" || fail "klip not idle: $("$C" printers)"
done
kill -TERM $pid; wait $pid; pid=
echo "farmd_mr_history: ok ($(( $(date +%s) - t0 )) s)"
