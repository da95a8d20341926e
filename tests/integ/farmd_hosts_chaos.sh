#!/usr/bin/env bash
# tests/integ/farmd_hosts_chaos.sh - issue 32's acceptance run: three
# slimfarmd hosts on one PostgreSQL (lib/pg.sh, with a loopback port), twelve
# simulated printers, four a host (two Marlins, a Moonraker, a PrusaLink),
# forty jobs submitted through the three APIs, and while they print:
#   1. kill -9 of host c while both its Marlins print, then its restart;
#   2. host b, whose store URL goes through a loopback proxy
#      (tests/tools/tcpproxy), cut off from the database while a Marlin and
#      a network printer of its print (the proxy drops every connection and
#      refuses new ones) until another host reaped it; b's network prints
#      then run to their end while it is still cut off; then reconnected;
#   3. PostgreSQL stopped (pg_ctl stop -m fast) for 30 s while at least
#      eight printers print, then started again.
# Each fault is placed while the prints it needs are provably under way,
# whatever this machine's pace: every simulator runs with the hold fault
# (slimfarm-sim --fault hold=$tmp/NAME.hold, sim/marlin/faults.h): while that
# file exists the printer holds at its next printing move, a slow printer to
# its host, and writes "held: ..." into the file.  The run arms the printers
# an event needs (creates their files), waits until they hold prints,
# places the fault, and releases them (removes the files).
# Leases: a's (60 s) outlives the outage, b's and c's (6 s) do not, so b and
# c may be reaped at the outage too (by whichever host is back first).
# Afterwards: the jobs table holds the forty jobs, each once; no job ran to
# the end twice; every simulator's executed log is exactly the G-code of the
# prints the store recorded on it (lib/farm.sh check_farm_logs, lib/netprint.sh
# check_net_logs: a start block run twice, a line lost or repeated fails);
# every job ends done, or interrupted where a USB (Marlin) print lost its
# host ("host NAME lost its lease", the host that owns the printer).  A
# network print is never left interrupted: its host takes it back once it
# joined again; one that ran to its end while its host was cut off and
# reaped must end done, not interrupted (an operator would print it again).
# No timing asserts: every wait polls with a generous bound; the outage's
# 30 s is the scenario.  100-140 s at load 20-40 on 2 cores (a Marlin's print
# lasts a few seconds at --speed 60, CHAOS_SPEED).  Env: BUILD.
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
. "$(dirname "$0")/lib/netprint.sh"
. "$(dirname "$0")/lib/pg.sh"
. "$(dirname "$0")/lib/hosts.sh"
t0=$(date +%s)
declare -A lease
chaos_cleanup() {
  [ -n "${PX_PID:-}" ] && kill "$PX_PID" 2> /dev/null
  hosts_cleanup
}
PG_TCP=1 hosts_store fsync=off
trap chaos_cleanup EXIT
note() { echo "   $(($(date +%s) - t0)) s: $*"; }

# host b's way to the database: a proxy to the server's port (commands on its stdin)
coproc PX { "$BUILD/tests/tools/tcpproxy" "$PG_PORT"; }
PX_PID=$PX_PID
read -r -t 30 line <&"${PX[0]}" || fail "tcpproxy did not start"
px_port=${line#port }
proxy() { echo "$1" >&"${PX[1]}" && read -r -t 30 line <&"${PX[0]}" && [ "$line" = "ok $1" ]; }

PRINTERS=
# host_ini NAME STORE_URL LEASE_S: $tmp/NAME.ini, host NAME with Marlins NAME_mk1, NAME_mk2,
# a Moonraker NAME_mr and a PrusaLink NAME_pl
host_ini() {
  local h=$1 p
  lease[$h]=$3
  {
    host_farm_ini "$h" "$3" "$2"
    for p in mk1 mk2; do
      printf '[printer %s_%s]\ndriver: marlin\nport: %s\nbaud: 1000000\nauto_eject: true\n' \
        "$h" "$p" "$(cat "$tmp/${h}_$p.addr")"
    done
    printf '[printer %s_mr]\ndriver: moonraker\nurl: %s\napi_key: %s-key\nauto_eject: true\n' \
      "$h" "$(cat "$tmp/${h}_mr.addr")" "$h"
    printf '[printer %s_pl]\ndriver: prusalink\nurl: %s\napi_key: %s-key\nauto_eject: true\n' \
      "$h" "$(cat "$tmp/${h}_pl.addr")" "$h"
  } > "$tmp/$h.ini"
}
joins() { grep -c "$1 joined (token" "$tmp/$1.log"; }

# A print lasts seconds (a few thousand lines): the farm prints through each event once
# its held prints go on
SPEED=${CHAOS_SPEED:-60}
hold() { echo "--fault hold=$tmp/$1.hold"; }
for h in a b c; do
  start_sim "${h}_mk1" --speed "$SPEED" $(hold "${h}_mk1")
  start_sim "${h}_mk2" --speed "$SPEED" $(hold "${h}_mk2")
  start_net "${h}_mr" moonraker --speed "$SPEED" --api-key "$h-key" $(hold "${h}_mr")
  start_net "${h}_pl" prusalink --speed "$SPEED" --api-key "$h-key" $(hold "${h}_pl")
  PRINTERS="$PRINTERS ${h}_mk1 ${h}_mk2 ${h}_mr ${h}_pl"
done
# arm PRINTER...: each holds at its next printing move; release PRINTER...: they go on;
# held PRINTER: it holds a print now (armed, and it reached a printing move)
arm() { for p in "$@"; do : > "$tmp/$p.hold"; done; }
release() { for p in "$@"; do rm -f "$tmp/$p.hold"; done; }
held() { [ -s "$tmp/$1.hold" ]; }
# held_list: the printers holding a print now
held_list() { for p in $PRINTERS; do held "$p" && echo "$p"; done | paste -sd' '; }
host_ini a "$URL" 60
host_ini b "$(pg_tcp_url postgres "$px_port")" 6
host_ini c "$URL" 6
for h in a b c; do start_host "$h"; done
idle4() { [ "$(on "$1" "$C" printers | grep -c "^$1_.* idle ")" -eq 4 ]; }
for h in a b c; do wait_for 90 idle4 "$h" || fail "$h's printers: $(on "$h" "$C" printers)"; done

# forty jobs through the three APIs in turn, in three batches: one before each event, so
# the farm prints through each (submit_batch N: N more)
for s in 8 9 10 11 12; do tetra "$tmp/t$s.stl" "$s"; done
jobs=
k=0
# submit_batch N [HOST]: N jobs through the three APIs in turn, or all for HOST's printers
# (through its API, one printer after the other: its four print at once, several jobs each)
submit_batch() {
  local n h id pin
  for n in $(seq "$1"); do
    h=${2:-$(echo a b c | cut -d' ' -f$((k % 3 + 1)))}
    pin=()
    [ -n "${2:-}" ] && pin=(--printer "${2}_$(echo mk1 mk2 mr pl | cut -d' ' -f$((n % 4 + 1)))")
    id=$(SLIMFARM_URL=${hurl[$h]} submit "$tmp/t$((8 + k % 5)).stl" --material PLA --method none "${pin[@]}")
    [ -n "$id" ] || fail "submit $k on $h"
    jobs="$jobs $id"
    k=$((k + 1))
  done
  note "$k jobs submitted"
}

# submit_to PRINTER: one job pinned to PRINTER, through its host's API
submit_to() {
  local id
  id=$(SLIMFARM_URL=${hurl[${1%%_*}]} submit "$tmp/t$((8 + k % 5)).stl" --material PLA --method none --printer "$1")
  [ -n "$id" ] || fail "submit $k to $1"
  jobs="$jobs $id"
  k=$((k + 1))
}
jobs_now() { psql_q 'SELECT id, state, printer FROM jobs ORDER BY id' | paste -sd' '; }

# usb_printing HOST: a job printing on one of HOST's Marlins (its id into $usb)
usb=
usb_printing() {
  usb=$(psql_q "SELECT id FROM jobs WHERE printer LIKE '$1\\_mk%' AND state = 'printing' LIMIT 1")
  [ -n "$usb" ]
}
# net_printing HOST: a job printing on one of HOST's network printers
net_printing() {
  [ -n "$(psql_q "SELECT id FROM jobs WHERE printer ~ '^$1_(mr|pl)\$' AND state = 'printing' LIMIT 1")" ]
}
# inflight HOST: HOST's printing jobs, "ID@PRINTER ..."
inflight() {
  psql_q "SELECT string_agg(id || '@' || printer, ' ' ORDER BY id) FROM jobs WHERE state = 'printing'
    AND printer LIKE '$1\_%'"
}
reaped_hosts() { cat "$tmp"/[abc].log | grep -c "reaped [0-9]* hosts"; }
errs=() # what fails after the run, each said in full before the test fails

# ---- 1. kill -9 of host c while both its Marlins print, then its restart ----
# A job pinned to each of c's Marlins first, held there, then twelve for any printer (held
# too: no printer runs ahead).  c's Marlins take no other job: a job that waited for one
# of them would wait on its interrupted print for good.
arm $PRINTERS
submit_to c_mk1
submit_to c_mk2
c_held() { held c_mk1 && held c_mk2 && [ "$(inflight c | grep -o '@c_mk' | wc -l)" = 2 ]; }
wait_for 300 c_held || fail "c's Marlins do not hold prints (held: $(held_list)): $(jobs_now)"
submit_batch 12
# (whichever hosts took them: at least two more printers hold prints)
n_held() { held_list | wc -w; }
c_mid_run() { [ "$(n_held)" -ge 4 ]; }
wait_for 300 c_mid_run || fail "no other printer holds a print (held: $(held_list)): $(jobs_now)"
c_jobs=$(inflight c)
kill -9 "${hpid[c]}"
wait "${hpid[c]}" 2> /dev/null
unset 'hpid[c]'
release $PRINTERS
note "killed c, printing $c_jobs"
c_joins=$(joins c)
start_host c
c_back() { [ "$(joins c)" -gt "$c_joins" ]; }
wait_for 90 c_back || fail "c did not join again: $(tail -5 "$tmp/c.log")"
note "c joined again"

# ---- 2. b cut off from the database while printing, until reaped; then reconnected ----
arm b_mk1 b_mk2 b_mr b_pl
submit_batch 13 b
# a Marlin's print and a network printer's held under way on b
b_both() { { held b_mk1 || held b_mk2; } && { held b_mr || held b_pl; } && usb_printing b && net_printing b; }
wait_for 300 b_both || fail "b's Marlins and network printers do not hold prints (held: $(held_list)): $(jobs_now)"
b_net=$(for p in b_mr b_pl; do held "$p" && echo "$p"; done | paste -sd' ')
b_joins=$(joins b)
b_jobs=$(inflight b)
proxy drop || fail "proxy drop"
note "b cut off from the database, printing $b_jobs"
b_reaped() { [ "$(psql_q "SELECT reaped_ms > 0 FROM hosts WHERE name = 'b'")" = t ]; }
wait_for 90 b_reaped || fail "b was never reaped while cut off: $(psql_q 'SELECT * FROM hosts')"
note "b reaped"
# b's held prints go on, cut off and reaped: its network ones run to their end so
release b_mk1 b_mk2 b_mr b_pl
# net_idle PRINTER: the simulator's own API says it prints nothing
net_idle() {
  local u st
  u=$(cat "$tmp/$1.addr")
  case $1 in
    *_mr) st=$(curl -sf -H "X-Api-Key: ${1%%_*}-key" "$u/printer/objects/query?print_stats" |
      json 'd["result"]["status"]["print_stats"]["state"]') ;;
    *_pl) st=$(curl -sf -H "X-Api-Key: ${1%%_*}-key" "$u/api/v1/status" | json 'd["printer"]["state"]') ;;
  esac
  [ -n "$st" ] && ! [[ $st =~ ^(printing|paused|PRINTING|PAUSED|BUSY|ATTENTION)$ ]]
}
b_net_done() { for p in $b_net; do net_idle "$p" || return 1; done; }
wait_for 300 b_net_done || fail "b's network prints did not end while it was cut off ($b_net)"
# and until b itself saw its Marlin prints end (b still drives its printers, cut off): a
# Marlin print still running when b joins again is interrupted there (a USB print cannot move
# hosts), its printer left for an operator, and part 3's job pinned to it would wait for good.
# b joins again at once now (its beat has a connection of its own), so the run waits for b's
# own view of its Marlins.  Not of its network printers: an end b's driver sees only after b
# joined again (b let the job go when its beat found the lease lost) must be recorded too:
# b holds the job again and takes the print back, or records its end.
b_all_done() { ! on b "$C" printers | grep -qE '^b_(mk1|mk2) .* (printing|paused) '; }
wait_for 300 b_all_done || fail "b's prints did not end while it was cut off: $(on b "$C" printers)"
proxy heal || fail "proxy heal"
note "b's prints ended ($b_net as the printers say, its Marlins as b saw them; b's view: $(on b "$C" printers | grep -E '^b_(mr|pl) ' | tr -s ' ' | cut -c1-50 | paste -sd';')); b reconnected"
b_back() { [ "$(joins b)" -gt "$b_joins" ]; }
wait_for 90 b_back || fail "b did not join again: $(tail -5 "$tmp/b.log")"
note "b joined again"

# ---- 3. PostgreSQL away for 30 s while the farm prints ----
# a job pinned to each printer that can print (not c's Marlins: their prints were
# interrupted with c), three for any: at least eight hold prints, whichever host prepared
# the others (a host takes all the queued jobs its printers may print, busy or not)
arm $PRINTERS
for p in a_mk1 a_mk2 a_mr a_pl b_mk1 b_mk2 b_mr b_pl c_mr c_pl; do submit_to "$p"; done
submit_batch 3
under_way() { [ "$(n_held)" -ge 8 ]; }
wait_for 300 under_way || fail "not printing before the outage (held: $(held_list)): $(jobs_now)"
held_out=$(held_list)
out_jobs="$(inflight a) $(inflight b) $(inflight c)"
note "PostgreSQL stops, printing $out_jobs; held: $held_out"
pg_ctl_as stop -m fast > /dev/null || fail "pg_ctl stop"
release $PRINTERS # the held prints go on (and end) while the database is away
sleep 30 # the scenario: the database away for 30 s
pg_ctl_as start > /dev/null || fail "pg_ctl start"
note "PostgreSQL back"
all_live() { [ "$("$C" hosts --store "$URL" | grep -cE '^[abc] +live')" = 3 ]; }
wait_for 120 all_live || fail "not every host live after the outage: $("$C" hosts --store "$URL")"

# ---- every job ends done, or interrupted where a Marlin print lost its host ----
settled() { [ "$(psql_q "SELECT count(*) FROM jobs WHERE state NOT IN ('done', 'interrupted')")" = 0 ]; }
wait_for 400 settled || fail "jobs not settled: $(psql_q "SELECT id, state, printer, claimed_by, reason FROM jobs WHERE state NOT IN ('done', 'interrupted') ORDER BY id")"
note "every job settled: $(psql_q "SELECT string_agg(state || ' ' || n, ', ') FROM (SELECT state, count(*) n FROM jobs GROUP BY state) s")"
# each once: forty rows, the forty ids the APIs gave
[ "$(psql_q 'SELECT count(*) FROM jobs')" = 40 ] || fail "jobs table holds $(psql_q 'SELECT count(*) FROM jobs') jobs, wanted 40"
[ "$(echo $jobs | tr ' ' '\n' | sort -u | wc -l)" = 40 ] || fail "submitted ids not distinct: $jobs"
[ "$(psql_q "SELECT string_agg(id::text, ' ' ORDER BY id) FROM jobs")" = "$(echo $jobs | tr ' ' '\n' | sort -n | tr '\n' ' ' | sed 's/ $//')" ] ||
  fail "jobs table ids differ from the submitted ones"
twice=$(psql_q "SELECT job_id FROM prints WHERE outcome = 'done' GROUP BY job_id HAVING count(*) > 1")
[ -z "$twice" ] || fail "jobs printed to the end twice: $twice"
# interrupted: only a Marlin's print, whose own host lost its lease
bad=$(psql_q "SELECT id || ' on ' || coalesce(printer, '-') || ': ' || reason FROM jobs WHERE state = 'interrupted'
  AND NOT (printer LIKE '%\\_mk_' AND reason LIKE '%host ' || split_part(printer, '_', 1) || ' lost its lease%')")
# (a network printer's print that ran to its end while its host was cut off and reaped:
# what the printer said of it, from its host's log)
if [ -n "$bad" ]; then
  while IFS= read -r line; do
    j=${line%% *}
    sha=$(psql_q "SELECT gcode_sha FROM jobs WHERE id = $j")
    pr=$(psql_q "SELECT printer FROM jobs WHERE id = $j")
    said=$(grep -h "printer\[$pr\]: job 'sf-$sha.gcode': done" "$tmp/${pr%%_*}.log" | head -1 | cut -c1-23)
    errs+=("job $line${said:+ (the printer reported it done at $said)}")
  done <<< "$bad"
  errs[0]="interrupted, not a Marlin print that lost its host: ${errs[0]}"
fi
for h in a b c; do kill -0 "${hpid[$h]}" 2> /dev/null || fail "host $h is not running: $(tail -5 "$tmp/$h.log")"; done

# no G-code started twice: each printer's executed log is its recorded prints' G-code, in order
SLIMFARM_URL=${hurl[a]}
stop_sims
check_farm_logs a_mk1 a_mk2 b_mk1 b_mk2 c_mk1 c_mk2 || errs+=("executed logs differ from the prints' G-code (Marlin)")
check_net_logs a_mr a_pl b_mr b_pl c_mr c_pl || errs+=("executed logs differ from the prints' G-code (network)")
note "jobs printing at the events: c killed: $c_jobs; b cut off: $b_jobs; outage: $out_jobs; now:
$(psql_q "SELECT string_agg(id || '@' || coalesce(nullif(printer, ''), (SELECT printer FROM prints
  WHERE job_id = jobs.id ORDER BY id DESC LIMIT 1)) || ' ' || state, ', ' ORDER BY id) FROM jobs
  WHERE id IN ($(echo "$c_jobs $b_jobs $out_jobs" | grep -o '[0-9]*@' | tr -d @ | paste -sd,))")"
[ ${#errs[@]} = 0 ] || fail "$(printf '%s\n' "${errs[@]}")"
for h in a b c; do kill -TERM "${hpid[$h]}"; wait "${hpid[$h]}"; unset "hpid[$h]"; done
echo "farmd_hosts_chaos: ok (40 jobs: $(psql_q "SELECT string_agg(state || ' ' || n, ', ') FROM (SELECT state, count(*) n FROM jobs GROUP BY state) s"); $(reaped_hosts) reaps; in $(($(date +%s) - t0)) s)"
