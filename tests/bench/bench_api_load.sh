#!/usr/bin/env bash
# bench_api_load.sh BUILD - does a read-only client slow a live print?
# (issue 30, case 1).  One slimfarmd over a history of BENCH_JOBS (10,000)
# finished jobs (written into its database before it starts, as
# tests/integ/lib/farm.sh's fill_jobs does), one simulated Marlin printing
# in real time (--speed 1, 115200 baud) a G-code of short moves uploaded
# through POST /api/files/local.  The same print runs alternately with no
# client and with BENCH_CLIENTS (5) read-only clients looping GET /api/jobs
# as fast as the daemon answers (one keep-alive connection each, one Python
# process each), BENCH_ROUNDS (2) times each, side by side in one run:
#  - the print's wall time (its print row: started_ms to ended_ms);
#  - the planner starvation the simulator counted during it (it ran dry
#    while the host had lines to send) and the seconds it stood dry;
#  - the clients' requests and bytes per second;
#  - the daemon's RSS before the first print and after the last.
# Reported: loaded / clean wall time as a ratio (target: within 2 %).  A
# print not done within BENCH_PRINT_MAX_S (240) is reported as ">240" with
# how far it got, and cancelled (main's code before issue 30 needed that).
# Loopback only; bounded: each print takes ~25 s, the run ~4 min.
set -u
build=${1:-build/rel}
BUILD=$build
jobs=${BENCH_JOBS:-10000}
clients=${BENCH_CLIENTS:-5}
rounds=${BENCH_ROUNDS:-2}
moves=${BENCH_MOVES:-700}
cap=${BENCH_PRINT_MAX_S:-240} # a print not done by then is reported as ">cap" and cancelled
. "$(dirname "$0")/../integ/lib/farm.sh"
fail() { echo "bench_api_load: $*"; tail -5 "$tmp/log" 2>/dev/null; exit 1; }
for b in "$D" "$C" "$S"; do [ -x "$b" ] || fail "$b not built"; done
py=/usr/bin/python3
RO=ro-bench-0123456789abcdef

# the printer: real time, the usual serial speed
"$S" marlin --baud 115200 --speed 1 --advanced-ok > "$tmp/sim.out" 2> "$tmp/sim.err" &
sim=$!
sims+=($sim)
for _ in $(seq 600); do [ -s "$tmp/sim.out" ] && break; sleep 0.05; done
addr=$(head -n 1 "$tmp/sim.out")
[ -n "$addr" ] || fail "the simulator did not start: $(cat "$tmp/sim.err")"
case "$addr" in /dev/*) addr="pty:$addr" ;; esac
cat > "$tmp/farm.ini" <<INI
[farm]
listen: 127.0.0.1:$port
data_dir: $tmp/data
api_keys: $RW
api_keys_readonly: $RO
[printer mk3]
driver: marlin
port: $addr
baud: 115200
material: PLA
auto_eject: true
gcode_models: *
INI
start_daemon
kill -TERM "$pid"; wait "$pid"; pid=
fill_jobs "$tmp/data/slimfarm.db" "$jobs" || fail "fill the store"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -q ' idle '" || fail "printer: $("$C" printers)"

# The G-code: short moves round a square, as a slicer's perimeters.
$py - "$moves" > "$tmp/part.gcode" <<'PY'
import math, sys
n = int(sys.argv[1])
print("G90\nM83\nG28\nG1 Z0.2 F3000")
for i in range(n):
    a = i * 0.02
    print("G1 X%.3f Y%.3f E0.02 F1800" % (100 + 40 * math.cos(a), 100 + 40 * math.sin(a)))
print("M84")
PY

stats() { # the simulator's counters now: "starved starved_s"
  local before; before=$(grep -c '^stats:' "$tmp/sim.err")
  kill -USR1 "$sim"
  for _ in $(seq 200); do [ "$(grep -c '^stats:' "$tmp/sim.err")" -gt "$before" ] && break; sleep 0.02; done
  grep '^stats:' "$tmp/sim.err" | tail -n 1 | tr ' ' '\n' |
    awk -F= '$1 == "starved" { s = $2 } $1 == "starved_s" { d = $2 } END { print s + 0, d + 0 }'
}

# print_once: upload the G-code, wait for its print to end; "wall_s starved dry_s"
print_once() {
  local st0 dr0 st1 dr1 id
  read -r st0 dr0 < <(stats)
  curl -sf -D "$tmp/up.h" -H "X-Api-Key: $RW" -F "file=@$tmp/part.gcode;filename=part.gcode" \
    -F print=true "$SLIMFARM_URL/api/files/local" > "$tmp/up.json" || fail "upload: $(cat "$tmp/up.json")"
  id=$(grep -i '^location:' "$tmp/up.h" | grep -o 'job-[0-9]*' | head -n 1)
  id=${id#job-}
  [ -n "$id" ] || fail "upload answered no job: $(cat "$tmp/up.h")"
  if ! wait_for "$cap" sh -c "curl -sf -m 60 -H 'X-Api-Key: $RW' '$SLIMFARM_URL/api/jobs/$id' | grep -q '\"state\":\"done\"\\|\"state\": \"done\"'"; then
    # not done within the cap: report how far it got, cancel it, go on
    local got
    read -r st1 dr1 < <(stats)
    got=$(api "/api/jobs/$id" | json '">%d(%d/%d_lines)" % ('"$cap"', d["job"]["lines_acked"], d["job"]["gcode_lines"])')
    curl -sf -m 120 -X POST -H "X-Api-Key: $RW" "$SLIMFARM_URL/api/jobs/$id/cancel" > /dev/null
    wait_for 300 sh -c "'$C' printers | grep -q ' idle '" || fail "printer not idle after job $id"
    echo "$got $((st1 - st0)) $($py -c "print('%.2f' % ($dr1 - $dr0))")"
    return
  fi
  read -r st1 dr1 < <(stats)
  wait_for 60 sh -c "'$C' printers | grep -q ' idle '" || fail "printer not idle after job $id"
  api "/api/jobs/$id" | json '"%.2f" % ((d["prints"][-1]["ended_ms"] - d["prints"][-1]["started_ms"]) / 1000)' |
    tr '\n' ' '
  echo "$((st1 - st0)) $($py -c "print('%.2f' % ($dr1 - $dr0))")"
}

# clients_start / clients_stop: the read-only clients, counting requests and bytes
clients_start() {
  cpids=()
  for ((c = 0; c < clients; c++)); do
    $py - "$http_port" "$RO" "$tmp/client.$c" 2>> "$tmp/clients.err" <<'PY' &
import http.client, os, signal, sys, time
port, key, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
n = b = 0
t0 = last = time.time()
def report():
    with open(out + ".tmp", "w") as f:
        f.write("%d %d %.3f\n" % (n, b, time.time() - t0))
    os.replace(out + ".tmp", out)
signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
while True:
    if time.time() - last > 0.5:
        report()
        last = time.time()
    conn.request("GET", "/api/jobs", headers={"X-Api-Key": key})
    r = conn.getresponse()
    body = r.read()
    if r.status != 200:
        sys.exit("GET /api/jobs: %d" % r.status)
    n += 1
    b += len(body)
PY
    cpids+=($!)
  done
}
clients_stop() {
  kill -TERM "${cpids[@]}" 2>/dev/null
  wait "${cpids[@]}" 2>/dev/null
  local k; k=$(ls "$tmp"/client.? 2>/dev/null | wc -l)
  [ "$k" -eq "$clients" ] || printf '(%s of %s clients reported: %s) ' "$k" "$clients" "$(tail -n 1 "$tmp/clients.err")"
  cat "$tmp"/client.? | awk '{ n += $1; b += $2; if ($3 > t) t = $3 } END { printf "%.0f req/s, %.1f MB/s\n", n / t, b / t / 1e6 }'
  rm -f "$tmp"/client.?
}

rss0=$(awk '$1 == "VmRSS:" { print $2 }' "/proc/$pid/status")
echo "slimfarmd over $jobs stored jobs; a print of $moves moves at 115200 baud, real time"
printf '%-8s %-6s %9s %8s %7s  %s\n' round run "wall s" starved "dry s" "clients"
clean=() loaded=()
for ((r = 1; r <= rounds; r++)); do
  read -r w st dry < <(print_once)
  clean+=("$w")
  printf '%-8s %-6s %9s %8s %7s  %s\n' "$r" clean "$w" "$st" "$dry" "-"
  clients_start
  sleep 1 # the clients are looping before the print starts
  read -r w st dry < <(print_once)
  rate=$(clients_stop)
  loaded+=("$w")
  printf '%-8s %-6s %9s %8s %7s  %s\n' "$r" loaded "$w" "$st" "$dry" "$clients x GET /api/jobs: $rate"
done
rss1=$(awk '$1 == "VmRSS:" { print $2 }' "/proc/$pid/status")
$py - "${clean[*]}" "${loaded[*]}" <<'PY'
import sys
# ">240(..)": not done within the cap; the ratio is then a lower bound
c = [float(x.lstrip(">").split("(")[0]) for x in sys.argv[1].split()]
l = [float(x.lstrip(">").split("(")[0]) for x in sys.argv[2].split()]
bound = ">" in sys.argv[2]
print("wall time, loaded / clean: %s%.3f (clean %s s, loaded %s s; target <= 1.02)"
      % (">" if bound else "", sum(l) / sum(c), "/".join(sys.argv[1].split()),
         "/".join(sys.argv[2].split())))
PY
echo "slimfarmd RSS: $((rss0 / 1024)) MB before the first print, $((rss1 / 1024)) MB after the last"
