#!/usr/bin/env bash
# tests/integ/farmd_hosts_remote.sh - an action on a printer another host
# owns, carried through the database (issue 32, "one farm from every host";
# farm_remote.h): three slimfarmd hosts on one PostgreSQL (lib/pg.sh), each
# with a simulated Marlin.
#
# Every host's GET /api/printers (and `slimfarm printers`) lists the whole
# farm, each printer with its host; another host's with the state that host
# wrote, "offline" once the host is down.  Through host a's API: b's Marlin, printing, is paused (200, the answer
# names host b and the state paused; the simulator's executed log shows the
# park move) and resumed (printing again); a refusal of b's own rules comes
# back with its status (409); a manual G-code line reaches c's Marlin.
# With b stopped (SIGSTOP: alive, leased, silent) a pause answers 504 at
# the wait's bound and its row is withdrawn; once b runs again it never
# pauses late.  With c killed and its lease run out, an action on its
# printer answers 503 naming the host down.  b's job, cancelled by its id
# through a, stops on b's printer.  No timing asserts: every wait
# polls with a generous bound.  Env: BUILD.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/pg.sh"
. "$(dirname "$0")/lib/hosts.sh"
t0=$(date +%s)
hosts_store

# host_ini NAME LEASE_S: $tmp/NAME.ini, host NAME with a Marlin NAME_mk
host_ini() {
  {
    host_farm_ini "$1" "$2"
    printf '[printer %s_mk]\ndriver: marlin\nport: %s\nbaud: 1000000\nauto_eject: true\n' \
      "$1" "$(cat "$tmp/${1}_mk.addr")"
  } > "$tmp/$1.ini"
}
# act HOST PRINTER ACTION [BODY]: POST through HOST's API; the status into $code, the body
# into $tmp/act.body, the time it took (s) into $took
act() {
  local path=/api/printers/$2/$3 out
  if [ -n "${4:-}" ]; then
    out=$(curl -s -o "$tmp/act.body" -w '%{http_code} %{time_total}' -X POST -H "X-Api-Key: $RW" \
      -H 'Content-Type: application/json' -d "$4" "${hurl[$1]}$path")
  else
    out=$(curl -s -o "$tmp/act.body" -w '%{http_code} %{time_total}' -X POST -H "X-Api-Key: $RW" "${hurl[$1]}$path")
  fi
  code=${out% *} took=${out#* }
}
body() { json "$1" < "$tmp/act.body"; }
parks() { grep -c '^G1 Z10.00 F600$' "$tmp/b_mk.log"; } # marlin_do_pause's lift

# b's Marlin is slow: its print lasts the whole test.  b's lease is long, so a SIGSTOP
# of b (below) is a host that does not answer, not a host down.
start_sim a_mk --speed 3000
start_sim b_mk --speed 5
start_sim c_mk --speed 3000
# a and c: 15-20 s leases, not 5: under a sanitizer on a loaded machine a 5 s lease ran out
# between beats.  c's lease must run out in the test: 15 s of it.
host_ini a 20
host_ini b 120
host_ini c 15
for h in a b c; do start_host "$h"; done
idle() { on "$1" "$C" printers | grep -qE "^${1}_mk +idle"; }
for h in a b c; do wait_for 60 idle "$h" || fail "$h: $(on "$h" "$C" printers)"; done

tetra "$tmp/t16.stl" 16
SLIMFARM_URL=${hurl[b]}
job=$(submit "$tmp/t16.stl" --material PLA --printer b_mk --method none)
printing() { [ "$(on a job_state "$job")" = printing ] && [ -s "$tmp/b_mk.log" ]; }
wait_for 120 printing || fail "job $job on b_mk: $(on a job_state "$job")"

# ---- pause and resume b's print through a ----
[ "$(parks)" = 0 ] || fail "b_mk parked before the pause"
act a b_mk pause
[ "$code" = 200 ] || fail "pause b_mk through a: $code $(cat "$tmp/act.body")"
took_pause=$took
[ "$(body 'd["printer"]["host"] + " " + d["printer"]["state"]')" = "b paused" ] ||
  fail "pause's answer: $(cat "$tmp/act.body")"
parked() { [ "$(parks)" = 1 ]; }
wait_for 60 parked || fail "b_mk's executed log shows no pause: $(tail -5 "$tmp/b_mk.log")"
on b "$C" printers | grep -qE '^b_mk +paused' || fail "b says: $(on b "$C" printers)"
# a lists the whole farm: its own printer and the others' as their hosts wrote them
listed() { on a api /api/printers | json '" ".join(p["name"] + ":" + p["host"] + ":" + p["state"] for p in d["printers"])'; }
farm_is() { [ "$(listed)" = "$1" ]; }
wait_for 30 farm_is "a_mk:a:idle b_mk:b:paused c_mk:c:idle" || fail "a lists: $(listed)"
grep -q "printer b_mk: pause from host a done" "$tmp/b.log" || fail "b's log: $(grep remote "$tmp/b.log")"
# the operator goes with it, as with a G-code line (the key's label, never the key)
[[ "$(psql_q "SELECT who FROM commands WHERE kind = 'pause' ORDER BY id LIMIT 1")" == "key "* ]] ||
  fail "the pause's operator: $(psql_q 'SELECT id, kind, who FROM commands ORDER BY id')"
act a b_mk resume
took_resume=$took
[ "$code" = 200 ] && [ "$(body 'd["printer"]["state"]')" = printing ] ||
  fail "resume b_mk through a: $code $(cat "$tmp/act.body")"
on b "$C" printers | grep -qE '^b_mk +printing' || fail "b says: $(on b "$C" printers)"
cli_lists() { on c "$C" printers | grep -qE '^b_mk +printing .*on host b'; }
wait_for 30 cli_lists || fail "slimfarm printers on c: $(on c "$C" printers)"
# b's own rules judge: a resume of a printing printer is "not now", with b's reason
act a b_mk resume
[ "$code" = 409 ] || fail "a second resume: $code $(cat "$tmp/act.body")"
grep -q "on host b" "$tmp/act.body" || fail "the refusal does not name b: $(cat "$tmp/act.body")"

# ---- a manual G-code line for c's idle Marlin, through a ----
act a c_mk command '{"command": "M117 from a"}'
[ "$code" = 200 ] && [ "$(body 'd["command"]')" = "M117 from a" ] ||
  fail "command on c_mk through a: $code $(cat "$tmp/act.body")"
sent() { grep -q '^M117 from a$' "$tmp/c_mk.log"; }
wait_for 30 sent || fail "c_mk did not run the line: $(tail -3 "$tmp/c_mk.log")"
act a nosuch pause
[ "$code" = 404 ] || fail "a printer no host owns: $code $(cat "$tmp/act.body")"

# ---- b stopped: no answer within the bound; the withdrawn pause never runs late ----
kill -STOP "${hpid[b]}"
s0=$SECONDS
act a b_mk pause
waited=$((SECONDS - s0))
[ "$code" = 504 ] || { kill -CONT "${hpid[b]}"; fail "pause of a stopped host's printer: $code $(cat "$tmp/act.body")"; }
grep -q "did not answer within 10 s" "$tmp/act.body" || fail "504's message: $(cat "$tmp/act.body")"
[ "$(psql_q "SELECT state FROM commands WHERE printer = 'b_mk' ORDER BY id DESC LIMIT 1")" = expired ] ||
  fail "the unanswered row: $(psql_q 'SELECT id, kind, state FROM commands ORDER BY id')"
kill -CONT "${hpid[b]}"
# once b answers a later command it has seen the withdrawn one: it must not have paused
answered() { act a b_mk resume; [ "$code" = 409 ]; }
wait_for 60 answered || fail "b does not answer after SIGCONT: $code $(cat "$tmp/act.body")"
[ "$(parks)" = 1 ] || fail "b_mk paused late: $(parks) parks"
on b "$C" printers | grep -qE '^b_mk +printing' || fail "b says: $(on b "$C" printers)"

# ---- c killed: its lease runs out, its printer is offline, host down ----
kill -9 "${hpid[c]}"
wait "${hpid[c]}" 2> /dev/null
unset 'hpid[c]'
down() { act a c_mk pause; [ "$code" = 503 ]; }
wait_for 60 down || fail "an action on a dead host's printer: $code $(cat "$tmp/act.body")"
grep -q "host c is down" "$tmp/act.body" || fail "503's message: $(cat "$tmp/act.body")"
wait_for 30 farm_is "a_mk:a:idle b_mk:b:printing c_mk:c:offline" || fail "a lists: $(listed)"
on a api /api/printers/c_mk | json 'd["printer"]["message"]' | grep -q "host c is down" ||
  fail "c_mk's message: $(on a api /api/printers/c_mk)"

# a cancel by a job's id that is not b_mk's job now (the printer took another meanwhile):
# b refuses it, 409-style, and b_mk prints on.  Written as a's cancel would write it.
other=$((job + 1000))
cid=$(psql_q "INSERT INTO commands(printer, host, from_host, kind, line, who, state, created_ms,
  deadline_ms) VALUES('b_mk', 'b', 'a', 'cancel-job', '$other', 'ops', 'pending',
  CAST(extract(epoch FROM clock_timestamp()) * 1000 AS BIGINT),
  CAST(extract(epoch FROM clock_timestamp()) * 1000 AS BIGINT) + 30000) RETURNING id;
  NOTIFY slimfarm_commands, 'b'" | head -1)
refused() { [ "$(psql_q "SELECT state || ' ' || rc FROM commands WHERE id = $cid")" = "done -5" ]; }
wait_for 60 refused || fail "b's answer to a cancel of job $other: $(psql_q "SELECT * FROM commands WHERE id = $cid")"
psql_q "SELECT message FROM commands WHERE id = $cid" | grep -q "job $other is not on printer b_mk now (job $job is): not cancelled" ||
  fail "the refusal's message: $(psql_q "SELECT message FROM commands WHERE id = $cid")"
[ "$(on a job_state "$job")" = printing ] || fail "job $job after a cancel of job $other: $(on a job_state "$job")"

# the print is b's to end: its job cancelled by id through a (b stops its printer, by the id)
code=$(curl -s -o "$tmp/act.body" -w '%{http_code}' -X POST -H "X-Api-Key: $RW" "${hurl[a]}/api/jobs/$job/cancel")
[ "$code" = 200 ] || fail "cancel job $job through a: $code $(cat "$tmp/act.body")"
cancelled() { [ "$(on a job_state "$job")" = cancelled ]; }
wait_for 60 cancelled || fail "job $job after the cancel: $(on a job_state "$job")"
[[ "$(psql_q "SELECT kind || ' ' || line || ' ' || who FROM commands ORDER BY id DESC LIMIT 1")" == "cancel-job $job key "* ]] ||
  fail "the cancel's row: $(psql_q 'SELECT id, kind, line, state FROM commands ORDER BY id')"
for h in a b; do kill -TERM "${hpid[$h]}"; wait "${hpid[$h]}"; unset "hpid[$h]"; done
echo "farmd_hosts_remote: ok (pause ${took_pause} s, resume ${took_resume} s through a; refusal, G-code, 504 after ${waited} s, host down; $(($(date +%s) - t0)) s)"
