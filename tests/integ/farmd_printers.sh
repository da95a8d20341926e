#!/usr/bin/env bash
# tests/integ/farmd_printers.sh - printers managed at run time through the
# REST API (api_printers.h, farm.h "Run-time printers"), against a
# simulated Marlin and a simulated OctoPrint, with a farm.ini that names
# no printer at all:
#  - bad fields are refused with 400 naming the field (farm.ini's own
#    checks); a read-only key gets 403;
#  - both printers are added at run time, connect, and each prints a job;
#  - while a job prints, its printer's connection cannot change, nor can it
#    be disabled or removed (409), while what the scheduler reads can;
#  - a printer with a part on its bed cannot be removed, nor disabled or
#    removed while idle with its heaters on (its driver would close with
#    nothing left to turn them off);
#  - a disabled printer (with its reason shown) takes no job: a job for it
#    waits, naming it disabled, through a daemon restart, and prints once
#    it is enabled;
#  - both printers, the disable and its reason survive the restart and a
#    reload (SIGHUP); a removed printer stays removed after a restart.
# Every wait polls for its condition with a bound generous for a loaded machine.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
RO=ro-key-0123456789abcdef

start_sim mk --speed 1
start_net op octoprint --speed 2000 --api-key op-key-0123
cp -r config/printers config/materials "$tmp/"
printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\napi_keys_readonly: %s\n' \
  "$port" "$tmp" "$RW" "$RO" > "$tmp/farm.ini"
start_daemon

# req METHOD PATH [BODY [KEY]]: the HTTP status on stdout, the reply in $tmp/r
req() {
  local body=()
  [ -n "${3:-}" ] && body=(-H 'Content-Type: application/json' --data "$3")
  curl -s -o "$tmp/r" -w '%{http_code}' -X "$1" -H "X-Api-Key: ${4:-$RW}" "${body[@]}" \
    "$SLIMFARM_URL$2"
}
# expect STATUS [TEXT] -- METHOD PATH [BODY [KEY]]: that status, and TEXT in the reply
expect() {
  local want=$1 text=$2 got; shift 3
  got=$(req "$@")
  [ "$got" = "$want" ] || fail "$1 $2: status $got, wanted $want: $(cat "$tmp/r")"
  [ -z "$text" ] || grep -qF -- "$text" "$tmp/r" || fail "$1 $2: reply lacks \"$text\": $(cat "$tmp/r")"
}
mk_body() { # MORE: the Marlin printer's body
  printf '{"name": "mk", "driver": "marlin", "port": "%s", "baud": 1000000, "material": "PLA", "gcode_models": "*", "auto_eject": false%s}' \
    "$(cat "$tmp/mk.addr")" "${1:-}"
}
op_body='{"name": "op", "driver": "octoprint", "url": "'$(cat "$tmp/op.addr")'", "api_key": "op-key-0123", "material": "PLA", "bed_size": [250, 210, 220], "auto_eject": true}'

# 400 naming the field, by farm.ini's rules
expect 400 "'nozzle_mm'" -- POST /api/printers "$(mk_body ', "nozzle_mm": 9')"
expect 400 "option 'port' is required" -- POST /api/printers '{"name": "mk", "driver": "marlin"}'
expect 400 "option 'driver': 'teapot'" -- POST /api/printers '{"name": "mk", "driver": "teapot", "port": "x"}'
expect 400 "option 'colour'" -- POST /api/printers "$(mk_body ', "colour": "red"')"
expect 400 "option 'url'" -- POST /api/printers '{"name": "op", "driver": "octoprint", "url": "ftp://x", "api_key": "k"}'
expect 400 "option 'api_key' is required" -- POST /api/printers '{"name": "op", "driver": "octoprint", "url": "http://127.0.0.1:9"}'
expect 400 "field 'name'" -- POST /api/printers '{"name": "m k", "driver": "marlin", "port": "x"}'
expect 400 "field 'name' is required" -- POST /api/printers '{"driver": "marlin", "port": "x"}'
expect 400 "field 'group'" -- POST /api/printers "$(mk_body ', "group": "a #b"')"
expect 400 "field 'bed_size'" -- POST /api/printers "$(mk_body ', "bed_size": {"x": 1}')"
expect 400 "JSON object" -- POST /api/printers '[1, 2]'
# read-only keys manage nothing
expect 403 "" -- POST /api/printers "$(mk_body)" "$RO"

# added at run time, both connect
expect 201 '"source":"api"' -- POST /api/printers "$(mk_body)"
expect 201 '"secrets":["api_key"]' -- POST /api/printers "$op_body"
grep -q 'op-key-0123' "$tmp/r" && fail "the reply shows op's api_key: $(cat "$tmp/r")"
expect 409 "exists" -- POST /api/printers "$op_body"
expect 403 "" -- DELETE /api/printers/op "" "$RO"
expect 403 "" -- POST /api/printers/op/disable '{"reason": "x"}' "$RO"
wait_for 60 sh -c "[ \$('$C' printers | grep -cE '^(mk|op) +idle ') -eq 2 ]" ||
  fail "printers: $("$C" printers)"

# upload_job FILE NAME: POST /api/files/local as PrusaSlicer does (only mk
# takes uploaded G-code); the new job's id
upload_job() {
  local c
  c=$(curl -s -o "$tmp/r" -w '%{http_code}' -H "X-Api-Key: $RW" -F print=true -F path= \
    -F "file=@$1;filename=$2" "$SLIMFARM_URL/api/files/local")
  [ "$c" = 201 ] || fail "upload $2: $c $(cat "$tmp/r")"
  json 'd["slimfarm"]["job_id"]' < "$tmp/r"
}
state_is() { [ "$(job_state "$1")" = "$2" ]; }
printer_is() { "$C" printers | grep -qE "^$1 +$2"; }

# a job prints on each
printf 'G90\nM83\nG1 X10 Y10 F6000\nG1 X20 Y20 E0.5 F1800\nM84\n' > "$tmp/short.gcode"
j1=$(upload_job "$tmp/short.gcode" short.gcode)
tetra "$tmp/t10.stl" 10
j2=$(submit "$tmp/t10.stl" --material PLA --printer op --method none)
wait_for 120 state_is "$j1" done || fail "job $j1 on mk: $(job_state "$j1"); $("$C" printers)"
wait_for 300 state_is "$j2" done || fail "job $j2 on op: $(job_state "$j2"); $("$C" printers)"
[ "$(api "/api/jobs/$j1" | json 'd["prints"][0]["printer"]')" = mk ] || fail "job $j1 not printed on mk"
[ "$(api "/api/jobs/$j2" | json 'd["prints"][0]["printer"]')" = op ] || fail "job $j2 not printed on op"
expect 200 "" -- POST /api/printers/mk/cleared

# while mk prints (one dwell a second, in real time): its link is fixed, the rest is not
{ printf 'G90\nM83\n'; for _ in $(seq 600); do printf 'G4 S1\n'; done; } > "$tmp/long.gcode"
j3=$(upload_job "$tmp/long.gcode" long.gcode)
wait_for 60 state_is "$j3" printing || fail "job $j3: $(job_state "$j3")"
expect 409 "option 'port' changed" -- PATCH /api/printers/mk '{"port": "tcp://127.0.0.1:9"}'
expect 409 "printing job $j3" -- POST /api/printers/mk/disable '{"reason": "nozzle swap"}'
expect 409 "printing job $j3" -- DELETE /api/printers/mk
expect 200 '"group":"g1"' -- PATCH /api/printers/mk '{"group": "g1"}'
[ "$(api /api/printers/mk | json 'd["printer"]["group"]')" = g1 ] || fail "mk's group: $(api /api/printers/mk)"
state_is "$j3" printing || fail "job $j3 after the edit: $(job_state "$j3")"
"$C" cancel "$j3" > /dev/null || fail "cancel $j3"
# its part stays on the bed: mk cannot go
wait_for 30 printer_is mk awaiting-clear || fail "mk: $("$C" printers)"
expect 409 "part on its bed" -- DELETE /api/printers/mk

# an idle printer with its heaters on (as one holding its heat for an interrupted print)
# keeps its driver: a disable or removal would close it with nothing left to turn them off
target_is() { [ "$(api "/api/printers/$1" | json '"%g" % d["printer"]["temps"]["nozzle_target_c"]')" = "$2" ]; }
expect 200 "" -- POST /api/printers/op/command '{"command": "M104 S200"}'
wait_for 60 target_is op 200 || fail "op's nozzle target: $(api /api/printers/op)"
expect 409 "heaters on" -- POST /api/printers/op/disable '{"reason": "nozzle swap"}'
expect 409 "heaters on" -- DELETE /api/printers/op
expect 200 "" -- POST /api/printers/op/command '{"command": "M104 S0"}'
wait_for 60 target_is op 0 || fail "op's nozzle target after M104 S0: $(api /api/printers/op)"

# a disabled printer takes no job, and says why it is disabled
expect 400 "field 'reason'" -- POST /api/printers/op/disable '{}'
expect 200 '"disabled_reason":"nozzle swap"' -- POST /api/printers/op/disable '{"reason": "nozzle swap"}'
[ "$(api /api/printers/op | json '"%s %s" % (d["printer"]["enabled"], d["printer"]["disabled_reason"])')" = "False nozzle swap" ] ||
  fail "op: $(api /api/printers/op)"
j4=$(submit "$tmp/t10.stl" --material PLA --printer op --method none)
waits_disabled() { api "/api/jobs/$j4" | json 'd["job"]["reason"]' | grep -q 'op: disabled'; }
wait_for 120 waits_disabled || fail "job $j4: $(job_state "$j4"): $(api "/api/jobs/$j4")"

# a restart keeps both printers, the disable and its reason, and mk's part on the bed
kill -TERM "$pid"; wait "$pid" 2> /dev/null; pid=
start_daemon
expect 200 '"source":"api"' -- GET /api/printers/mk/config
expect 200 '"disabled_reason":"nozzle swap"' -- GET /api/printers/op/config
[ "$(api /api/printers/op | json '"%s %s" % (d["printer"]["enabled"], d["printer"]["disabled_reason"])')" = "False nozzle swap" ] ||
  fail "op after the restart: $(api /api/printers/op)"
wait_for 60 printer_is mk awaiting-clear || fail "mk after the restart: $("$C" printers)"
wait_for 120 waits_disabled || fail "job $j4 after the restart: $(api "/api/jobs/$j4")"
case "$(job_state "$j4")" in queued | preparing | ready) ;; *) fail "job $j4: $(job_state "$j4")" ;; esac
# a reload (SIGHUP) of a farm.ini that names neither keeps both as they are
kill -HUP "$pid"
wait_for 30 grep -q "reloaded " "$tmp/log" || fail "no reload"
names=$(api /api/printers | json '" ".join(sorted("%s:%s" % (p["name"], p["enabled"]) for p in d["printers"]))')
[ "$names" = "mk:True op:False" ] || fail "printers after the reload: $names"

# enabled again, it prints the job that waited
expect 200 '"enabled":true' -- POST /api/printers/op/enable
wait_for 300 state_is "$j4" done || fail "job $j4 after the enable: $(job_state "$j4"); $("$C" printers)"

# removed once its bed is clear, and gone for good
expect 200 "" -- POST /api/printers/mk/cleared
expect 200 '"removed":"mk"' -- DELETE /api/printers/mk
expect 404 "" -- GET /api/printers/mk
kill -TERM "$pid"; wait "$pid" 2> /dev/null; pid=
start_daemon
names=$(api /api/printers | json '" ".join(p["name"] for p in d["printers"])')
[ "$names" = op ] || fail "printers after the second restart: '$names'"
echo "farmd_printers: ok"
