#!/usr/bin/env bash
# tests/integ/farmd_hosts_view.sh - the whole farm from either host (issue
# 32, "one farm from every host"; farm_view.h, store_view.h): two slimfarmd
# hosts on one PostgreSQL (lib/pg.sh), each with a simulated Marlin.
#
# Host a's event stream (GET /api/events) carries b's printer going
# printing and back, b's job's events, and b's print's progress with its
# host; a's GET /api/printers shows b's printer with the temperatures b
# reads from it (not zeros) and a's printer, disabled on a, as disabled
# on b; a's /metrics has b's printer's series labelled host="b" beside
# a's own labelled host="a", the farm-wide job counts, and its loop and
# store queue series unlabelled.  No timing asserts: every wait polls
# with a generous bound.  Env: BUILD.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/pg.sh"
. "$(dirname "$0")/lib/hosts.sh"
t0=$(date +%s)
hosts_store
sse=
view_cleanup() { [ -n "$sse" ] && kill "$sse" 2> /dev/null; hosts_cleanup; }
trap view_cleanup EXIT

# host_ini NAME LEASE_S: $tmp/NAME.ini, host NAME with a Marlin NAME_mk
host_ini() {
  {
    host_farm_ini "$1" "$2"
    printf '[printer %s_mk]\ndriver: marlin\nport: %s\nbaud: 1000000\nauto_eject: true\n' \
      "$1" "$(cat "$tmp/${1}_mk.addr")"
  } > "$tmp/$1.ini"
}
start_sim a_mk --speed 3000
start_sim b_mk --speed 5
host_ini a 20
host_ini b 20
for h in a b; do start_host "$h"; done
idle() { on "$1" "$C" printers | grep -qE "^${1}_mk +idle"; }
for h in a b; do wait_for 60 idle "$h" || fail "$h: $(on "$h" "$C" printers)"; done

# a's event stream, from before b's print
curl -sN -H "X-Api-Key: $RW" "${hurl[a]}/api/events" > "$tmp/a.sse" 2> /dev/null &
sse=$!
# a printer's (or job's) events on a's stream: "KIND DETAIL" lines
events() { grep -A1 '^event: ' "$tmp/a.sse" | grep '^data: ' | sed 's/^data: //' |
  json_lines "$1"; }
json_lines() { /usr/bin/python3 -c "
import json, sys
for l in sys.stdin:
    try: d = json.loads(l)
    except ValueError: continue
    if isinstance(d, dict) and ($1): print(d['kind'], d['detail'])"; }

tetra "$tmp/t16.stl" 16
SLIMFARM_URL=${hurl[b]}
job=$(submit "$tmp/t16.stl" --material PLA --printer b_mk --method none)
printing() { [ "$(on b job_state "$job")" = printing ] && [ -s "$tmp/b_mk.log" ]; }
wait_for 120 printing || fail "job $job on b_mk: $(on b job_state "$job")"

# ---- a's stream: b's printer going printing, b's job, b's progress with its host ----
saw_printing() { events "d['printer'] == 'b_mk'" | grep -q '^printer-state printing$'; }
wait_for 60 saw_printing || fail "a's stream has no b_mk printing: $(tail -c 2000 "$tmp/a.sse")"
saw_job() { events "d['job_id'] == $job" | grep -q '^job-start'; }
wait_for 30 saw_job || fail "a's stream has no start of b's job $job: $(events "d['job_id'] == $job")"
# progress: a snapshot each tick, b's print among them, named with its host
progress_of_b() { grep -A1 '^event: progress' "$tmp/a.sse" | grep '^data: ' | sed 's/^data: //' |
  /usr/bin/python3 -c "
import json, sys
for l in sys.stdin:
    for p in json.loads(l):
        if p['printer'] == 'b_mk': print(p['host'], p['job_id'], p['state'], p['progress'])" | tail -1; }
saw_progress() { [[ "$(progress_of_b)" == "b $job printing "* ]]; }
wait_for 60 saw_progress || fail "a's stream: no progress of b_mk: $(grep -A1 '^event: progress' "$tmp/a.sse" | tail -4)"

# ---- a lists b's printer with its temperatures, as b reads them ----
temps_of() { on "$1" api "/api/printers/$2" |
  json '"%d %d %s" % (d["printer"]["temps"]["nozzle_c"], d["printer"]["temps"]["nozzle_target_c"], d["printer"]["enabled"])'; }
b_says=$(temps_of b b_mk)
hot() { set -- $(temps_of a b_mk); [ "$1" -ge 100 ] && [ "$2" -ge 100 ] && [ "$3" = True ]; }
wait_for 60 hot || fail "a shows b_mk: $(temps_of a b_mk) (b says $b_says)"
# and a's printer, disabled on a, is disabled on b
code=$(curl -s -o "$tmp/act.body" -w '%{http_code}' -X POST -H "X-Api-Key: $RW" \
  -H 'Content-Type: application/json' -d '{"reason": "nozzle swap"}' "${hurl[a]}/api/printers/a_mk/disable")
[ "$code" = 200 ] || fail "disable a_mk: $code $(cat "$tmp/act.body")"
disabled_on_b() { [ "$(on b api /api/printers/a_mk | json '"%s %s" % (d["printer"]["enabled"], d["printer"]["disabled_reason"])')" = "False nozzle swap" ]; }
wait_for 30 disabled_on_b || fail "b shows a_mk: $(on b api /api/printers/a_mk)"

# ---- a's /metrics: the whole farm ----
on a api /metrics > "$tmp/metrics" || fail "a's /metrics"
metric() { grep -E "^$1 " "$tmp/metrics" | awk '{ print $2 }'; }
hot_metric() {
  on a api /metrics > "$tmp/metrics" || return 1
  local v; v=$(metric 'slimfarm_printer_temperature_celsius\{printer="b_mk",host="b",sensor="nozzle"\}')
  [ -n "$v" ] && [ "${v%.*}" -ge 100 ]
}
wait_for 30 hot_metric || fail "a's /metrics has no hot b_mk: $(grep b_mk "$tmp/metrics")"
[ "$(metric 'slimfarm_printer_state\{printer="b_mk",host="b",state="printing"\}')" = 1 ] ||
  fail "b_mk's state on a: $(grep slimfarm_printer_state "$tmp/metrics")"
grep -qE '^slimfarm_printer_state\{printer="a_mk",host="a",state="[a-z ]+"\} 1$' "$tmp/metrics" ||
  fail "a_mk's state on a: $(grep slimfarm_printer_state "$tmp/metrics")"
[ "$(metric 'slimfarm_printers\{state="printing"\}')" = 1 ] ||
  fail "printers printing on a: $(grep '^slimfarm_printers' "$tmp/metrics")"
[ "$(metric 'slimfarm_jobs\{state="printing"\}')" = 1 ] ||
  fail "jobs printing on a (b's job): $(grep '^slimfarm_jobs' "$tmp/metrics")"
grep -qE '^slimfarm_loop_turn_max_seconds [0-9.]+$' "$tmp/metrics" ||
  fail "a's loop series: $(grep loop "$tmp/metrics")"

# ---- b's print ends (cancelled on b): a's stream sees b's printer leave printing ----
code=$(curl -s -o "$tmp/act.body" -w '%{http_code}' -X POST -H "X-Api-Key: $RW" "${hurl[b]}/api/jobs/$job/cancel")
[ "$code" = 200 ] || fail "cancel job $job on b: $code $(cat "$tmp/act.body")"
left() { events "d['printer'] == 'b_mk'" | tail -1 | grep -qvE '^printer-state (printing|paused)$'; }
wait_for 60 left || fail "a's stream after the cancel: $(events "d['printer'] == 'b_mk'" | tail -3)"
saw_cancel() { events "d['job_id'] == $job" | grep -q 'cancel'; }
wait_for 30 saw_cancel || fail "a's stream: job $job's cancel: $(events "d['job_id'] == $job")"
for h in a b; do kill -TERM "${hpid[$h]}"; wait "${hpid[$h]}"; unset "hpid[$h]"; done
echo "farmd_hosts_view: ok ($(($(date +%s) - t0)) s)"
