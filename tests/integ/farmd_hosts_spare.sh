#!/usr/bin/env bash
# tests/integ/farmd_hosts_spare.sh - a host with spare cores prepares jobs
# for another host's printer (issue 32: "any host with spare cores may
# prepare any queued job"; farm_spare.c): two slimfarmd hosts on one
# PostgreSQL (lib/pg.sh), "rack" with a simulated Marlin and "big" with no
# printers at all.
#
# rack joins and publishes its printer's settings, then stands still with
# its simulator (SIGSTOP: its lease still runs, so its printer is a live
# host's; it prepares nothing meanwhile); jobs submitted through big's API are claimed
# and prepared by big for rack's printer and handed over ready, held by no
# host (a "job-hand-over" event each).  rack, going on (SIGCONT), takes
# and prints every job: each done, printed once on rack_mk (its executed
# log holds exactly the stored G-code of each print), and big started
# nothing.  No timing asserts: every wait polls with a generous bound.
# Env: BUILD.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/pg.sh"
. "$(dirname "$0")/lib/hosts.sh"
t0=$(date +%s)
hosts_store

# host_ini NAME: $tmp/NAME.ini, host NAME (a lease far above the test's stop of rack)
host_ini() {
  host_farm_ini "$1" 300 > "$tmp/$1.ini"
}
start_sim rack_mk --speed 3000
host_ini rack
printf '[printer rack_mk]\ndriver: marlin\nport: %s\nbaud: 1000000\nauto_eject: true\n' \
  "$(cat "$tmp/rack_mk.addr")" >> "$tmp/rack.ini"
host_ini big
start_host rack
start_host big
published() { [ "$(psql_q "SELECT host || ' ' || profile FROM host_printers WHERE printer = 'rack_mk'")" = "rack generic-marlin" ]; }
wait_for 60 published || fail "rack_mk not published: $(psql_q "SELECT * FROM host_printers")"
live2() { [ "$(psql_q "SELECT count(*) FROM hosts WHERE reaped_ms = 0")" = 2 ]; }
wait_for 60 live2 || fail "hosts: $("$C" hosts --store "$URL")"

# rack stands still, and its Marlin with it (a printer whose host stopped reading would fill
# the pty with its temperature reports meanwhile): only big may prepare now
kill -STOP "$sim_rack_mk" "${hpid[rack]}"
for s in 8 9 10; do tetra "$tmp/t$s.stl" "$s"; done
jobs=
for s in 8 9 10; do
  id=$(SLIMFARM_URL=${hurl[big]} submit "$tmp/t$s.stl" --material PLA --method none)
  [ -n "$id" ] || fail "submit on big"
  jobs="$jobs $id"
done
handed() { [ "$(psql_q "SELECT count(*) FROM jobs WHERE state = 'ready' AND claimed_by = ''")" = 3 ]; }
wait_for 120 handed || fail "not prepared by big: $(psql_q "SELECT id, state, claimed_by FROM jobs") $(tail -20 "$tmp/big.log")"
n=$(psql_q "SELECT count(*) FROM events WHERE kind = 'job-hand-over' AND detail LIKE '%host ''big'' prepared it%'")
[ "$n" = 3 ] || fail "hand-over events: $n"
grep -q "claiming it to prepare here for host rack's printer rack_mk" "$tmp/big.log" ||
  fail "big did not say so: $(tail -20 "$tmp/big.log")"

# rack goes on: it takes the ready jobs no host holds and prints each once
kill -CONT "$sim_rack_mk" "${hpid[rack]}"
all_done() {
  local j
  for j in $jobs; do [ "$(on big job_state "$j")" = done ] || return 1; done
}
wait_for 180 all_done || fail "not all done: $(psql_q "SELECT id, state, claimed_by, printer FROM jobs") $(tail -20 "$tmp/rack.log")"
[ "$(psql_q "SELECT count(*) FROM prints WHERE printer = 'rack_mk' AND outcome = 'done'")" = 3 ] ||
  fail "prints: $(psql_q "SELECT job_id, printer, outcome FROM prints")"
[ "$(psql_q "SELECT count(*) FROM prints WHERE printer != 'rack_mk'")" = 0 ] || fail "a print elsewhere"
stop_sims
SLIMFARM_URL=${hurl[rack]} check_farm_logs rack_mk || fail "rack_mk's executed log"
echo "farmd_hosts_spare: ok (3 jobs prepared on big, printed on rack; $(($(date +%s) - t0)) s)"
