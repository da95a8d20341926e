#!/usr/bin/env bash
# tests/integ/farmd_history.sh - the farm's history through a real daemon
# printing on a simulated Marlin: GET /api/jobs finds the finished job by a
# piece of its name and exports it as CSV (printer, filament, print time),
# POST /api/jobs/ID/again queues a new job from the same file and options,
# which prints too, GET /api/stats counts the prints for the printer, and
# GET /api/printers/NAME/temps holds the temperatures sampled meanwhile.
# Every wait polls for its condition.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"

start_sim mk3 --speed 3000
one_printer_ini mk3 true
start_daemon
wait_for 60 sh -c "'$C' printers | grep -q ' idle '" || fail "printer: $("$C" printers)"

tetra "$tmp/Corner-Bracket.stl" 10
tetra "$tmp/hook.stl" 8
id=$(submit "$tmp/Corner-Bracket.stl" --method none --copies 1)
hid=$(submit "$tmp/hook.stl" --method none)
is_done() { [ "$(job_state "$1")" = done ]; }
wait_for 300 is_done "$id" || fail "job $id: $(job_state "$id")"
wait_for 300 is_done "$hid" || fail "job $hid: $(job_state "$hid")"

# search, JSON and CSV
api "/api/jobs?name=bracket&state=done" | json '[j["id"] for j in d["jobs"]]' | grep -qx "\[$id\]" \
  || fail "search: $(api '/api/jobs?name=bracket')"
curl -sf -D "$tmp/h" -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/jobs?name=bracket&format=csv" > "$tmp/jobs.csv" \
  || fail "csv"
grep -qi '^Content-Type: text/csv' "$tmp/h" || fail "csv type: $(cat "$tmp/h")"
/usr/bin/python3 - "$tmp/jobs.csv" "$id" <<'PY' || fail "csv: $(cat "$tmp/jobs.csv")"
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1], newline="")))
assert len(rows) == 1, rows
r = rows[0]
assert r["id"] == sys.argv[2] and r["name"] == "Corner-Bracket.stl" and r["state"] == "done", r
assert r["printer"] == "mk3" and r["copies_done"] == "1" and r["finished"].endswith("Z"), r
assert float(r["filament_g"]) > 0 and int(r["print_s"]) >= 0, r
PY
code=$(curl -s -o /dev/null -w '%{http_code}' -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/jobs?format=pdf")
[ "$code" = 400 ] || fail "format=pdf: $code"

# print again
again=$(curl -sf -X POST -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/jobs/$id/again" | json 'd["job"]["id"]') \
  || fail "again"
[ "$again" -gt "$hid" ] || fail "again gave job $again"
api "/api/jobs/$again" | json 'd["job"]["name"]' | grep -qx "Corner-Bracket.stl" || fail "again: name"
wait_for 300 is_done "$again" || fail "job $again: $(job_state "$again")"
code=$(curl -s -o /dev/null -w '%{http_code}' -X POST -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/jobs/9999/again")
[ "$code" = 404 ] || fail "again of no job: $code"

# statistics: three prints done on mk3 today
check_stats() {
  api "/api/stats?days=3" | /usr/bin/python3 -c '
import json, sys
d = json.load(sys.stdin)
assert d["days"] == 3, d
p = [x for x in d["printers"] if x["printer"] == "mk3"][0]
assert p["prints"]["done"] == 3 and p["success_rate"] == 1.0, p
assert len(p["utilisation"]) == 3 and p["utilisation"][2] > 0, p
'
}
check_stats || fail "stats: $(api '/api/stats?days=3')"
code=$(curl -s -o /dev/null -w '%{http_code}' -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/stats?days=0")
[ "$code" = 400 ] || fail "days=0: $code"
# the temperature history: sampled every 5 s, kept by the daemon
has_temps() {
  api "/api/printers/mk3/temps" | /usr/bin/python3 -c '
import json, sys
d = json.load(sys.stdin)
assert d["printer"] == "mk3" and d["interval_ms"] == 5000, d
assert d["samples"] and isinstance(d["samples"][-1][1], float), d
'
}
wait_for 60 has_temps || fail "temps: $(api /api/printers/mk3/temps)"
code=$(curl -s -o /dev/null -w '%{http_code}' -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/printers/nope/temps")
[ "$code" = 404 ] || fail "temps of no printer: $code"
# the history page and its script are served like the dashboard's files
for f in history.html history.js; do
  curl -sf -o /dev/null "$SLIMFARM_URL/$f" || fail "$f not served"
done
echo "farmd_history: ok"
