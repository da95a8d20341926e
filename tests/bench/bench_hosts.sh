#!/usr/bin/env bash
# bench_hosts.sh BUILD - several slimfarmd hosts on one PostgreSQL against
# one SQLite host (issue 32): real daemons, figures side by side.
#
# Claims: BENCH_HOSTS_JOBS (10,000) queued jobs of one small part (a 10 mm
# tetrahedron, method none: preparing is one quick slice), copied straight
# into the store from one job submitted through the API (the part's file is
# then in the store, shared by SHA-256).  Then 1, 3 and 10 hosts on one
# PostgreSQL (farm.ini `store: postgresql://...`, `host: NAME`), and one
# host on its own SQLite, each host with one printer that is offline (a
# Marlin on a port that is not there: the scheduler prepares for it,
# nothing prints), claim and prepare as the daemon does (farm_host.h: a
# host claims only for a printer of its own).  Over BENCH_HOSTS_S (12)
# seconds, once every host is up: the jobs that left the queue per second
# (on PostgreSQL each is a claim, SKIP LOCKED; on SQLite the PREPARE), and
# the API's latency on the first host meanwhile under a steady read load:
# one keep-alive client sending GET /api/jobs (its first page) and GET
# /api/printers in turn, 20 a second (a reply later than its slot sends the
# next at once: no coordinated-omission correction), p50, p99 and the
# slowest.  Next to them, with the daemons stopped, the store alone:
# bench_claims.c's claims per second with as many claimers on
# BENCH_HOSTS_STORE_N (2,000) jobs (what the store allows; the daemons'
# rate is what their scheduling passes make of it); and the statements
# PostgreSQL spent most time on with the most hosts.
#
# Cost per printer: one host on PostgreSQL with 1, 4 and 12 simulated
# Marlins (one slimfarm-sim --count process, real time), idle for
# BENCH_HOSTS_COST_S (15) seconds, then as long with each printing an
# uploaded G-code of short moves (about 37 lines a second), counted from
# when every print is past its 100th line: what the host made PostgreSQL
# do, from pg_stat_statements over the host's database (BEGIN and COMMIT
# count as statements): statements a second, rows written (by statements
# starting INSERT, UPDATE, DELETE or WITH) and WAL kB a minute, with the
# G-code lines a second the stored progress moved (a printing host's cost
# follows its lines: progress is saved every 16 lines, printer.c); per
# printer = the host's total / its printers, and the slope between the
# fewest and the most printers (what one more printer adds); then the
# host's most frequent statements while printing.
#
# Wall figures on a shared machine: the 1-minute load average is printed
# next to each.  Never fails on time; about 3-4 minutes on 2 shared cores.
# Env: BENCH_HOSTS_JOBS, BENCH_HOSTS_S, BENCH_HOSTS_COUNTS ("1 3 10"),
# BENCH_HOSTS_STORE_N, BENCH_HOSTS_PRINTERS ("1 4 12"), BENCH_HOSTS_COST_S.
set -u
build=${1:-build/rel}
BUILD=$build
jobs=${BENCH_HOSTS_JOBS:-10000}
win=${BENCH_HOSTS_S:-12}
counts=${BENCH_HOSTS_COUNTS:-1 3 10}
printers=${BENCH_HOSTS_PRINTERS:-1 4 12}
cwin=${BENCH_HOSTS_COST_S:-15}
sjobs=${BENCH_HOSTS_STORE_N:-2000}
. "$(dirname "$0")/../integ/lib/farm.sh"
. "$(dirname "$0")/../integ/lib/pg.sh"
py=/usr/bin/python3
fail() { echo "bench_hosts: $*"; exit 1; }
for b in "$D" "$C" "$S"; do [ -x "$b" ] || fail "$b not built"; done
declare -A hpid
all_cleanup() {
  for h in "${!hpid[@]}"; do kill -9 "${hpid[$h]}" 2> /dev/null; done
  cleanup
  pg_stop
}
pg_start shared_preload_libraries=pg_stat_statements > "$tmp/pg.out" 2>&1 ||
  fail "no PostgreSQL: $(cat "$tmp/pg.out")"
trap all_cleanup EXIT
psql_q() { psql -qAt "$1" -c "$2"; }
psql_q "$PG_URL" 'CREATE EXTENSION pg_stat_statements' || fail "pg_stat_statements"
cp -r config/printers config/materials "$tmp/"
tetra "$tmp/part.stl" 10
load1() { cut -d' ' -f1 /proc/loadavg; }

# host_ini NAME URL [PRINTERS]: $tmp/NAME.ini; URL "" for SQLite; PRINTERS: the
# addresses of its printers, one a line (none: one offline Marlin NAME_p)
host_ini() {
  local h=$1 url=$2 addrs=${3:-} i=0 a
  {
    printf '[farm]\nlisten: 127.0.0.1:0\ndata_dir: %s/%s\napi_keys: %s\nprofiles_dir: %s\n' \
      "$tmp" "$h" "$RW" "$tmp"
    [ -n "$url" ] && printf 'store: %s\nhost: %s\n' "$url" "$h"
    if [ -z "$addrs" ]; then
      printf '[printer %s_p]\ndriver: marlin\nport: pty:%s/none/%s\nbaud: 1000000\n' "$h" "$tmp" "$h"
    fi
    for a in $addrs; do
      printf '[printer %s_p%d]\ndriver: marlin\nport: pty:%s\nbaud: 1000000\nauto_eject: true\n' \
        "$h" "$i" "$a"
      printf 'gcode_models: *\n'
      i=$((i + 1))
    done
  } > "$tmp/$h.ini"
}
# start_host NAME: slimfarmd on $tmp/NAME.ini, logging to $tmp/NAME.log; its URL in $tmp/NAME.url
start_host() {
  daemon_start "$tmp/$1.ini" "$tmp/$1.log" || fail "host $1 did not come up: $(tail -n 5 "$tmp/$1.log")"
  hpid[$1]=$pid
  echo "$SLIMFARM_URL" > "$tmp/$1.url"
  pid=
}
# gone PID: the process exited (a zombie until it is waited for: kill -0 still finds it)
gone() {
  local st
  st=$(cut -d' ' -f3 "/proc/$1/stat" 2> /dev/null)
  [ -z "$st" ] || [ "$st" = Z ]
}
# stop_host NAME: SIGTERM (the host leaves), SIGKILL if it is not gone within 60 s
stop_host() {
  local p=${hpid[$1]:-}
  [ -n "$p" ] || return 0
  kill -TERM "$p" 2> /dev/null
  wait_for 60 gone "$p" || { echo "  (host $1 stopped by SIGKILL)"; kill -9 "$p"; }
  wait "$p" 2> /dev/null
  unset "hpid[$1]"
}

# seed NAME URL: one job of the part through host NAME's API, for a printer that is not
# there (no host claims it), then stop the host: the part's file is in its store
seed() {
  host_ini "$1" "$2"
  start_host "$1"
  SLIMFARM_URL=$(cat "$tmp/$1.url") submit "$tmp/part.stl" --printer ghost --method none > /dev/null
  stop_host "$1"
}

# The queue: the seed job copied to $jobs queued jobs for any printer, in queue order (without
# the reason a single host wrote on it: fits no printer).
fill_sql() { # COLS: the jobs' columns but id and queue_pos
  echo "UPDATE jobs SET target_printer = '', reason = '';
        INSERT INTO jobs($1, queue_pos) SELECT $1, g FROM jobs,
        (WITH RECURSIVE n(g) AS (SELECT 2 UNION ALL SELECT g + 1 FROM n WHERE g < $jobs)
         SELECT g FROM n) AS s WHERE id = (SELECT min(id) FROM jobs);"
}
pg_cols="SELECT string_agg(column_name, ',' ORDER BY ordinal_position) FROM information_schema.columns
         WHERE table_name = 'jobs' AND column_name NOT IN ('id', 'queue_pos')"
URL=$(pg_url seed)
psql_q "$PG_URL" 'CREATE DATABASE seed' && "$D" --init-store "$URL" > /dev/null || fail "init-store"
seed seed "$URL"
psql_q "$URL" "$(fill_sql "$(psql_q "$URL" "$pg_cols")")" || fail "fill PostgreSQL"
[ "$(psql_q "$URL" "SELECT count(*) FROM jobs WHERE state = 'queued'")" = "$jobs" ] || fail "fill: count"
seed lite ""
$py - "$tmp/lite/slimfarm.db" "$(fill_sql X)" <<'PY' || fail "fill SQLite"
import sqlite3, sys
db = sqlite3.connect(sys.argv[1])
cols = ",".join(r[1] for r in db.execute("PRAGMA table_info(jobs)") if r[1] not in ("id", "queue_pos"))
db.executescript(sys.argv[2].replace("X", cols))
db.commit()
PY
mv "$tmp/lite" "$tmp/lite.seed"

# The reader: GET /api/jobs and /api/printers in turn at RATE a second for SECS on PORT;
# prints "requests errors p50_ms p99_ms max_ms".
cat > "$tmp/reader.py" <<'PY'
import http.client, sys, time
port, key, secs, rate = int(sys.argv[1]), sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
lat, errors, k = [], 0, 0
conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
t0 = time.monotonic()
slot = t0
while time.monotonic() - t0 < secs:
    path = ("/api/jobs", "/api/printers")[k % 2]
    k += 1
    t = time.perf_counter()
    try:
        conn.request("GET", path, headers={"X-Api-Key": key})
        r = conn.getresponse()
        r.read()
        if r.status != 200:
            errors += 1
    except OSError:
        errors += 1
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    lat.append((time.perf_counter() - t) * 1000)
    slot += 1 / rate
    time.sleep(max(0, slot - time.monotonic()))
lat.sort()
n = len(lat)
print(n, errors, "%.1f %.1f %.1f" % (lat[n // 2], lat[min(n - 1, int(n * 0.99))], lat[-1]) if n else "- - -")
PY

# A row of the claims table: ENGINE K: start K hosts (from the seeded queue), time the window.
rows=()
claims_run() {
  local eng=$1 k=$2 url="" i h0 left0 left1 t0 t1 rd
  if [ "$eng" = PostgreSQL ]; then
    psql_q "$PG_URL" "CREATE DATABASE hosts$k TEMPLATE seed" || fail "database hosts$k"
    url=$(pg_url "hosts$k")
  fi
  local p=pg$k # the hosts' names: pgKhI, liteKhI
  [ -z "$url" ] && p=lite$k
  for ((i = 0; i < k; i++)); do
    host_ini "${p}h$i" "$url"
    [ -z "$url" ] && cp -r "$tmp/lite.seed" "$tmp/${p}h$i"
    start_host "${p}h$i"
  done
  queued() {
    if [ -n "$url" ]; then psql_q "$url" "SELECT count(*) FROM jobs WHERE state = 'queued'"
    else
      $py -c "import sqlite3, sys; print(sqlite3.connect(sys.argv[1]).execute(
        \"SELECT count(*) FROM jobs WHERE state = 'queued'\").fetchone()[0])" "$tmp/${p}h0/slimfarm.db"
    fi
  }
  h0=$(cat "$tmp/${p}h0.url")
  left0=$(queued)
  t0=$(date +%s.%N)
  rd=$($py "$tmp/reader.py" "${h0##*:}" "$RW" "$win" 20)
  left1=$(queued)
  t1=$(date +%s.%N)
  local n_req errs p50 p99 slowest spread=-
  read -r n_req errs p50 p99 slowest <<< "$rd"
  # the jobs each host holds (claimed), fewest-most: do they all get a share?
  [ -n "$url" ] && spread=$(psql_q "$url" "SELECT min(n) || '-' || max(n) FROM (SELECT count(*) AS n
    FROM jobs WHERE claimed_by <> '' GROUP BY claimed_by) c")
  rows+=("$(printf '%-10s %5s %8.1f %7s %9s %8s %8s %8s %7s %6s' "$eng" "$k" \
    "$(echo "($left0 - $left1) / ($t1 - $t0)" | bc -l)" "$((jobs - left1))" "${spread:--}" \
    "${p50:--}" "${p99:--}" "${slowest:--}" "${n_req:--}/${errs:--}" "$(load1)")")
  for ((i = 0; i < k; i++)); do stop_host "${p}h$i"; done
  # the store alone, for comparison: bench_claims.c's K claimers draining $sjobs jobs
  local sc=- surl=
  if [ -x "$build/bench/bench_claims" ]; then
    if [ -n "$url" ]; then
      psql_q "$PG_URL" "CREATE DATABASE claims$k" && surl=$(pg_url "claims$k")
    fi
    sc=$("$build/bench/bench_claims" "$tmp/claims-$p" "$sjobs" "$k" $surl 2>&1 |
      sed -n 's/.* = *\([0-9]*\) claims\/s.*/\1/p')
    [ -n "$surl" ] && psql_q "$PG_URL" "DROP DATABASE claims$k"
  fi
  rows[${#rows[@]} - 1]+=$(printf ' %8s' "${sc:--}")
  [ -n "$url" ] || return 0
  # where PostgreSQL's time went: the hosts' statements by their total time
  ctop=$(psql_q "$PG_URL" "SELECT calls, round(total_exec_time::numeric / calls, 2), rows / calls,
    left(regexp_replace(query, '\s+', ' ', 'g'), 80) FROM pg_stat_statements
    WHERE dbid = (SELECT oid FROM pg_database WHERE datname = 'hosts$k')
    ORDER BY total_exec_time DESC LIMIT 4" | tr '|' ' ')
  ck=$k
  psql_q "$PG_URL" "DROP DATABASE hosts$k"
}

echo "claims: $jobs queued jobs, a ${win} s window per row once every host is up; $(uptime | sed 's/.*load/load/')"
claims_run SQLite 1
for k in $counts; do claims_run PostgreSQL "$k"; done
printf '%-10s %5s %8s %7s %9s %8s %8s %8s %7s %6s %8s\n' engine hosts claims/s claimed \
  "per host" "API p50" "API p99" "API max" req/err load1 "store/s"
for r in "${rows[@]}"; do echo "$r"; done
echo "(claimed: jobs out of the queue at the window's end, start-up included; per host: the fewest"
echo " and most jobs a host held; API: ms on the first host, GET /api/jobs and /api/printers in turn"
echo " at 20/s while the hosts claim (requests/errors);"
echo " store/s: claims/s of the store alone, bench_claims.c, K claimers on $sjobs jobs, no daemon)"
if [ -n "${ck:-}" ]; then
  echo "PostgreSQL's most costly statements with $ck hosts (calls, mean ms, rows a call; over the run):"
  echo "$ctop" | sed 's/^/  /'
fi

# ---- the cost a host adds to PostgreSQL per printer ----
# A G-code of short moves round a circle (0.8 mm at 30 mm/s: 37 lines a second in real time,
# the simulator has no acceleration), longer than the wait for its 100th line and the window.
moves=$(((cwin + 30) * 37))
$py - "$moves" > "$tmp/long.gcode" <<'PY'
import math, sys
n = int(sys.argv[1])
print("G90\nM83\nG28\nG1 Z0.2 F3000\nG1 X90 Y50 F9000")
for i in range(n):
    a = i * 0.02
    print("G1 X%.3f Y%.3f E0.02 F1800" % (50 + 40 * math.cos(a), 50 + 40 * math.sin(a)))
print("M84")
PY
# stats DB: "statements rows_written wal_bytes" of database DB so far (pg_stat_statements)
# and the G-code lines its jobs' stored progress says were printed
stats() {
  echo "$(psql_q "$PG_URL" "SELECT coalesce(sum(calls), 0), coalesce(sum(rows) FILTER (WHERE query ~*
    '^\s*(insert|update|delete|with)'), 0), coalesce(sum(wal_bytes), 0) FROM pg_stat_statements
    WHERE dbid = (SELECT oid FROM pg_database WHERE datname = '$1')
    AND query NOT LIKE '%sum(lines_acked)%'" | tr '|' ' ')" \
    "$(psql_q "$(pg_url "$1")" 'SELECT coalesce(sum(lines_acked), 0) FROM jobs')"
}
# cost_window DB: the window's "statements/s rows/min wal_kB/min lines/s"
cost_window() {
  local s0 s1
  s0=$(stats "$1")
  sleep "$cwin"
  s1=$(stats "$1")
  echo "$s0 $s1" | awk -v w="$cwin" '{ printf "%.1f %.0f %.0f %.1f\n", ($5 - $1) / w,
    ($6 - $2) * 60 / w, ($7 - $3) * 60 / w / 1024, ($8 - $4) / w }'
}
crows=()
cost_run() {
  local n=$1 h=cost$1 url addrs sim k printing idle busy
  psql_q "$PG_URL" "CREATE DATABASE $h" || fail "database $h"
  url=$(pg_url "$h")
  "$D" --init-store "$url" > /dev/null || fail "init-store $h"
  "$S" marlin --count "$n" --baud 1000000 --speed 1 --advanced-ok > "$tmp/$h.sim" 2> "$tmp/$h.simerr" &
  sim=$!
  sims+=($sim)
  wait_for 30 sh -c "[ \$(wc -l < '$tmp/$h.sim') -ge $n ]" || fail "sims: $(cat "$tmp/$h.simerr")"
  addrs=$(cat "$tmp/$h.sim")
  host_ini "$h" "$url" "$addrs"
  start_host "$h"
  export SLIMFARM_URL
  SLIMFARM_URL=$(cat "$tmp/$h.url")
  wait_for 60 sh -c "[ \$('$C' printers | grep -c ' idle ') -ge $n ]" ||
    echo "  ($h: $("$C" printers | grep -c ' idle ') of $n printers idle)"
  idle=$(cost_window "$h")
  idle_load=$(load1)
  for ((k = 0; k < n; k++)); do
    curl -sf -H "X-Api-Key: $RW" -F "file=@$tmp/long.gcode;filename=long.gcode" -F print=true \
      "$SLIMFARM_URL/api/files/local" > /dev/null || fail "upload"
  done
  wait_for 60 sh -c "[ \$('$C' printers | grep -c ' printing ') -ge $n ]" ||
    echo "  ($h: $("$C" printers | grep -c ' printing ') of $n printing)"
  # past the homing and the first travel: every job's stored progress moving
  wait_for 60 sh -c "[ \$(psql -qAt '$url' -c \"SELECT count(*) FROM jobs WHERE state = 'printing'
    AND lines_acked >= 100\") -ge $n ]" || echo "  ($h: not every print past its 100th line)"
  # from here the counts are the printing window's alone (the top statements below)
  psql_q "$PG_URL" "SELECT pg_stat_statements_reset(0, (SELECT oid FROM pg_database
    WHERE datname = '$h'), 0)" > /dev/null
  busy=$(cost_window "$h")
  printing=$("$C" printers | grep -c ' printing ')
  # where it goes: the host's most frequent statements while its printers print
  top=$(psql_q "$PG_URL" "SELECT calls, left(regexp_replace(query, '\s+', ' ', 'g'), 90)
    FROM pg_stat_statements WHERE dbid = (SELECT oid FROM pg_database WHERE datname = '$h')
    AND query NOT LIKE '%sum(lines_acked)%' ORDER BY calls DESC LIMIT 8" | tr '|' ' ')
  crows+=("$n $idle $idle_load $busy $(load1) $printing")
  stop_host "$h"
  kill "$sim" 2> /dev/null
  wait "$sim" 2> /dev/null
  psql_q "$PG_URL" "DROP DATABASE $h"
}
for n in $printers; do cost_run "$n"; done
echo "the cost a host adds to PostgreSQL, by its printers (simulated Marlins, real time): ${cwin} s idle,"
echo "then ${cwin} s each printing (lines/s: G-code lines the stored progress moved; per printer: the"
echo "host's figures / printers; slope: (at $(echo $printers | awk '{ print $NF }') - at $(echo $printers | awk '{ print $1 }') printers) / the printers' difference)"
$py - "${crows[@]}" <<'PY'
import sys
rows = [[float(x) for x in r.split()] for r in sys.argv[1:]]
# a row: printers, idle (stmt/s rows/min WAL lines/s), load, printing (the same four), load, printing
print("%8s | %8s %9s %9s %5s | %8s %9s %9s %7s %5s %4s" % ("printers", "stmt/s", "rows/min",
      "WALkB/min", "load1", "stmt/s", "rows/min", "WALkB/min", "lines/s", "load1", "prt"))
print("%8s | %35s | %48s" % ("", "idle", "printing"))
def per(r, d):
    return "%8.2f %9.1f %9.1f %5s | %8.2f %9.1f %9.1f %7.1f" % (r[1] / d, r[2] / d, r[3] / d, "",
                                                            r[6] / d, r[7] / d, r[8] / d, r[9] / d)
for r in rows:
    print("%8d | %8.1f %9.0f %9.0f %5.2f | %8.1f %9.0f %9.0f %7.1f %5.2f %4d" % (
        r[0], r[1], r[2], r[3], r[5], r[6], r[7], r[8], r[9], r[10], r[11]))
    print("%8s | %s" % ("/printer", per(r, r[0])))
if len(rows) > 1 and rows[-1][0] > rows[0][0]:
    a, b = rows[0], rows[-1]
    print("%8s | %s" % ("slope", per([0] + [y - x for x, y in zip(a[1:], b[1:])], b[0] - a[0])))
PY
echo "the most frequent statements of the host with $(echo $printers | awk '{ print $NF }') printers while they print (calls):"
echo "$top" | sed 's/^/  /'
