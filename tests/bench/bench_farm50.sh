#!/usr/bin/env bash
# bench_farm50.sh BUILD - one slimfarmd driving 50 simulated Marlin printers
# at once, printing real G-code in real time, side by side with the same 50
# printers driven by 50 Printrun printcore hosts (one Python process each,
# the usual way to run a farm of Marlin printers without a daemon).
#
# Setup: `slimfarm shapes` parts, one job per printer (--method none: the
# daemon slices them with its own slicer, round robin over the parts), a
# profile copied from generic-marlin without the M190/M109 waits (the sim
# heats in real time too; the window should measure streaming, not 50 s of
# heat-up).  The printers are one `slimfarm-sim --count 50` process (ptys,
# --speed 1, --baud, ADVANCED_OK): each is a full simulated Marlin, they
# share one epoll loop so 50 simulator processes do not crowd the two cores
# the hosts are measured on.
#
# Window: once every printer prints, after BENCH_WARMUP s, for BENCH_SECS s:
#  - host CPU: utime+stime over wall from /proc/PID/stat (the daemon; the
#    sum of the 50 Python processes for the peer), RSS from /proc/PID/status;
#  - per printer, from the simulator's stats (SIGUSR1 before and after):
#    commands executed per second, planner starvation (the planner ran dry
#    while the host had lines to send) and the seconds it stood dry;
#  - REST latency: GET /api/printers with curl every 0.2 s, p50/p99/max.
# The peer prints the very G-code files the daemon printed (same printer,
# same job).
#
# Then the network variant, printed beside it: a fresh slimfarmd with the
# same $n jobs on $n `driver: octoprint` printers, one `slimfarm-sim
# octoprint --count $n` process at --speed 1; the daemon uploads each job
# and polls every printer (GET /api/job + /api/printer each poll_ms) while
# the simulated OctoPrint streams.  Same window: the daemon's CPU and RSS,
# the simulator's CPU, GET /api/printers p50/p99/max, and the ratios of
# CPU and p99 against the Marlin row (serial streaming vs HTTP polling).
#
# BENCH_PRINTERS (50), BENCH_SECS (60), BENCH_WARMUP (10), BENCH_BAUD
# (115200), BENCH_PEER=0 skips printcore, BENCH_NET=0 skips the network
# variant, BENCH_SIM_PROCS=1 runs one Marlin simulator process per printer.
set -u
umask 077 # slimfarmd refuses a farm.ini holding keys that others can read
build=${1:-build/rel}
n=${BENCH_PRINTERS:-50}
secs=${BENCH_SECS:-60}
warm=${BENCH_WARMUP:-10}
baud=${BENCH_BAUD:-115200}
peer=${BENCH_PEER:-1}
procs=${BENCH_SIM_PROCS:-0}
D=$build/bin/slimfarmd
C=$build/bin/slimfarm
S=$build/bin/slimfarm-sim
for b in "$D" "$C" "$S"; do [ -x "$b" ] || { echo "bench_farm50: $b not built"; exit 1; }; done
py=/usr/bin/python3
work=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null; done
  wait 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
hz=$(getconf CLK_TCK)
key=bench-key-0123456789abcdef
port=$((20000 + RANDOM % 20000))
export SLIMFARM_URL=http://127.0.0.1:$port SLIMFARM_API_KEY=$key
api() { curl -sf -H "X-Api-Key: $key" "$SLIMFARM_URL$1"; }
now() { date +%s.%N; }
# cpu_ticks PID...: utime+stime of the processes, clock ticks
cpu_ticks() {
  local t=0 p
  for p in "$@"; do
    t=$((t + $(awk '{ sub(/.*\) /, ""); print $12 + $13 }' "/proc/$p/stat" 2>/dev/null || echo 0)))
  done
  echo "$t"
}
# rss_kb FIELD PID...: VmRSS or VmHWM summed, kB
rss_kb() {
  local f=$1 t=0 p; shift
  for p in "$@"; do t=$((t + $(awk -v f="$f:" '$1 == f { print $2 }' "/proc/$p/status" 2>/dev/null || echo 0))); done
  echo "$t"
}

# sim_start NAME: the $n printers, their addresses in order in $work/NAME.out;
# one `--count $n` process, or with BENCH_SIM_PROCS=1 one process each (to
# see what 50 simulator processes cost).
sim_start() {
  local i
  sim_pids=()
  if [ "$procs" = 1 ]; then
    for ((i = 0; i < n; i++)); do
      "$S" marlin --baud "$baud" --speed 1 --advanced-ok > "$work/$1.out.$i" 2> "$work/$1.err.$i" &
      sim_pids+=($!); pids+=($!)
    done
    for ((i = 0; i < n; i++)); do
      for _ in $(seq 100); do [ -s "$work/$1.out.$i" ] && break; sleep 0.05; done
      head -n 1 "$work/$1.out.$i"
    done > "$work/$1.out"
  else
    "$S" marlin --count "$n" --baud "$baud" --speed 1 --advanced-ok \
      > "$work/$1.out" 2> "$work/$1.err" &
    sim_pids+=($!); pids+=($!)
  fi
  for _ in $(seq 100); do [ "$(wc -l < "$work/$1.out")" -ge "$n" ] && return 0; sleep 0.05; done
  echo "bench_farm50: the simulator did not start: $(head -c 300 "$work/$1.err"*)"; exit 1
}
# snapshot NAME TAG: ask the simulators for their stats lines -> $work/NAME.TAG, one per printer
snapshot() {
  local i f
  if [ "$procs" = 1 ]; then
    for ((i = 0; i < n; i++)); do
      f="$work/$1.err.$i"
      echo $(( $(grep -c '^stats:' "$f") + 1 )) > "$f.want"
    done
    kill -USR1 "${sim_pids[@]}"
    for ((i = 0; i < n; i++)); do
      f="$work/$1.err.$i"
      for _ in $(seq 100); do [ "$(grep -c '^stats:' "$f")" -ge "$(cat "$f.want")" ] && break; sleep 0.02; done
      grep '^stats:' "$f" | tail -n 1
    done > "$work/$1.$2"
    return
  fi
  local before; before=$(grep -c '^stats:' "$work/$1.err")
  kill -USR1 "${sim_pids[@]}"
  for _ in $(seq 100); do
    [ "$(grep -c '^stats:' "$work/$1.err")" -ge $((before + n)) ] && break; sleep 0.02
  done
  grep '^stats:' "$work/$1.err" | sed -n "$((before + 1)),$((before + n))p" > "$work/$1.$2"
}
# window_stats NAME WALL: per-printer deltas between NAME.a and NAME.b ->
# "lines/s min avg max | starved total, printers starved | dry s"
window_stats() {
  paste -d ' ' "$work/$1.a" "$work/$1.b" | awk -v wall="$2" -v n="$n" '
    function f(k, from,   i, kv) { for (i = from; i <= NF; i++) { split($i, kv, "=");
        if (kv[1] == k) return kv[2] } return 0 }
    { half = NF / 2
      ex = f("executed", half + 1) - f("executed", 1)
      st = f("starved", half + 1) - f("starved", 1)
      dry = f("starved_s", half + 1) - f("starved_s", 1)
      lps = ex / wall; sum += lps; if (NR == 1 || lps < lo) lo = lps; if (lps > hi) hi = lps
      starved += st; if (st > 0) hit++; drys += dry }
    END { printf "%.1f %.1f %.1f %d %d %.2f\n", lo, sum / n, hi, starved, hit, drys }'
}
pct() { # SORTED_FILE P -> the P-th percentile (nearest rank)
  awk -v p="$2" '{ v[NR] = $1 } END { if (!NR) { print "-"; exit }
    k = int(p / 100 * NR + 0.999); if (k < 1) k = 1; printf "%.1f", v[k] * 1000 }' "$1"
}

"$C" shapes "$work/parts" > /dev/null
parts=(arch frame lbracket mushroom tee torus)
cp -r config/printers config/materials "$work/"
sed -E '/^[[:space:]]+M(190|109) /d' config/printers/generic-marlin.cfg > "$work/printers/bench-marlin.cfg"

# ---- ours: slimfarmd ----
sim_start ours
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$work" "$key"
  for ((i = 0; i < n; i++)); do
    printf '[printer p%d]\ndriver: marlin\nport: pty:%s\nbaud: %s\nprofile: bench-marlin\n' \
      "$i" "$(sed -n "$((i + 1))p" "$work/ours.out")" "$baud"
    printf 'material: PLA\nbed_size: 250, 210, 210\nauto_eject: true\n'
  done
} > "$work/farm.ini"
"$D" -c "$work/farm.ini" > "$work/daemon.log" 2>&1 &
dpid=$!
pids+=("$dpid")
for _ in $(seq 100); do api /api/printers > /dev/null 2>&1 && break; sleep 0.1; done
for ((i = 0; i < n; i++)); do
  "$C" submit "$work/parts/${parts[i % ${#parts[@]}]}.stl" --printer "p$i" --method none \
    --material PLA > /dev/null || { echo "bench_farm50: submit $i failed"; exit 1; }
done
printing() { # -> number of printers printing
  api /api/printers | $py -c 'import json,sys
print(sum(p["state"] == "printing" for p in json.load(sys.stdin)["printers"]))' 2>/dev/null || echo 0
}
t_sub=$(now)
for _ in $(seq 600); do [ "$(printing)" -ge "$n" ] && break; sleep 0.5; done
got=$(printing)
[ "$got" -ge "$n" ] || { echo "bench_farm50: only $got of $n printers printing"; tail -5 "$work/daemon.log"; exit 1; }
echo "all $n printers printing $(awk -v a="$t_sub" -v b="$(now)" 'BEGIN { printf "%.0f", b - a }') s after submit (slicing on the daemon's pool); warm-up ${warm} s, window ${secs} s"
sleep "$warm"
load0=$(cut -d ' ' -f 1-3 /proc/loadavg)
c0=$(cpu_ticks "$dpid"); s0=$(cpu_ticks "${sim_pids[@]}"); t0=$(now)
snapshot ours a
: > "$work/lat"
end=$(awk -v t="$t0" -v s="$secs" 'BEGIN { printf "%.3f", t + s }')
while awk -v e="$end" -v t="$(now)" 'BEGIN { exit !(t < e) }'; do
  curl -s -o /dev/null -w '%{time_total}\n' -H "X-Api-Key: $key" "$SLIMFARM_URL/api/printers" >> "$work/lat"
  sleep 0.2
done
snapshot ours b
t1=$(now); c1=$(cpu_ticks "$dpid"); s1=$(cpu_ticks "${sim_pids[@]}")
load1=$(cut -d ' ' -f 1-3 /proc/loadavg)
wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }')
ours_cpu=$(awk -v c=$((c1 - c0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
ours_sim=$(awk -v c=$((s1 - s0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
ours_rss=$(( $(rss_kb VmRSS "$dpid") / 1024 ))
ours_hwm=$(( $(rss_kb VmHWM "$dpid") / 1024 ))
read -r o_lo o_avg o_hi o_st o_hit o_dry < <(window_stats ours "$wall")
sort -g "$work/lat" > "$work/lat.s"
o_p99=$(pct "$work/lat.s" 99)
lat="$(pct "$work/lat.s" 50)/$o_p99/$(pct "$work/lat.s" 100) ms ($(wc -l < "$work/lat") GETs)"
still=$(printing)
# The G-code each printer got, for the peer.
mkdir -p "$work/gcode"
api /api/jobs | $py -c 'import json,sys
for j in json.load(sys.stdin)["jobs"]: print(j["target_printer"] or "-", j["gcode_sha"] or "-")' |
while read -r p sha; do
  f=$(find "$work/data" -type f -name "$sha*" | head -n 1)
  [ -n "$f" ] && cp "$f" "$work/gcode/$p.gcode"
done
kill "$dpid" "${sim_pids[@]}"; wait "$dpid" "${sim_pids[@]}" 2>/dev/null
echo "slimfarmd: window ${wall%.*} s, load $load0 -> $load1, $still of $n still printing at the end"

# ---- ours, network printers: slimfarmd polling $n OctoPrint simulators ----
# The same parts and profile, the same daemon, but every printer is
# `driver: octoprint` on one `slimfarm-sim octoprint --count $n` process
# (--speed 1): the daemon uploads each job and then only polls (GET /api/job
# and /api/printer every poll_ms, 1 s by default) while OctoPrint streams.
net_row=
if [ "${BENCH_NET:-1}" = 1 ]; then
  nkey=octo-bench-key
  nport=$((port + 1))
  export SLIMFARM_URL=http://127.0.0.1:$nport
  mkdir -p "$work/up"
  "$S" octoprint --count "$n" --speed 1 --api-key "$nkey" --uploads "$work/up/p" \
    > "$work/net.out" 2> "$work/net.err" &
  npid=$!; pids+=($!); nt_start=$(now)
  for _ in $(seq 100); do [ "$(wc -l < "$work/net.out")" -ge "$n" ] && break; sleep 0.05; done
  [ "$(wc -l < "$work/net.out")" -ge "$n" ] ||
    { echo "bench_farm50: the octoprint simulator did not start: $(head -c 300 "$work/net.err")"; exit 1; }
  {
    printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/ndata\napi_keys: %s\n' "$nport" "$work" "$key"
    for ((i = 0; i < n; i++)); do
      printf '[printer p%d]\ndriver: octoprint\nurl: %s\napi_key: %s\nprofile: bench-marlin\n' \
        "$i" "$(sed -n "$((i + 1))p" "$work/net.out")" "$nkey"
      printf 'material: PLA\nbed_size: 250, 210, 210\nauto_eject: true\n'
    done
  } > "$work/nfarm.ini"
  "$D" -c "$work/nfarm.ini" > "$work/ndaemon.log" 2>&1 &
  ndpid=$!; pids+=("$ndpid")
  for _ in $(seq 100); do api /api/printers > /dev/null 2>&1 && break; sleep 0.1; done
  for ((i = 0; i < n; i++)); do
    "$C" submit "$work/parts/${parts[i % ${#parts[@]}]}.stl" --printer "p$i" --method none \
      --material PLA > /dev/null || { echo "bench_farm50: octoprint submit $i failed"; exit 1; }
  done
  t_sub=$(now)
  for _ in $(seq 600); do [ "$(printing)" -ge "$n" ] && break; sleep 0.5; done
  got=$(printing)
  if [ "$got" -ge "$n" ]; then
    echo "octoprint: all $n printers printing $(awk -v a="$t_sub" -v b="$(now)" 'BEGIN { printf "%.0f", b - a }') s after submit"
    sleep "$warm"
    load0=$(cut -d ' ' -f 1-3 /proc/loadavg)
    c0=$(cpu_ticks "$ndpid"); s0=$(cpu_ticks "$npid"); t0=$(now)
    : > "$work/nlat"
    end=$(awk -v t="$t0" -v s="$secs" 'BEGIN { printf "%.3f", t + s }')
    while awk -v e="$end" -v t="$(now)" 'BEGIN { exit !(t < e) }'; do
      curl -s -o /dev/null -w '%{time_total}\n' -H "X-Api-Key: $key" "$SLIMFARM_URL/api/printers" >> "$work/nlat"
      sleep 0.2
    done
    t1=$(now); c1=$(cpu_ticks "$ndpid"); s1=$(cpu_ticks "$npid")
    load1=$(cut -d ' ' -f 1-3 /proc/loadavg)
    wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }')
    net_cpu=$(awk -v c=$((c1 - c0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
    net_sim=$(awk -v c=$((s1 - s0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
    net_rss=$(( $(rss_kb VmRSS "$ndpid") / 1024 ))
    net_hwm=$(( $(rss_kb VmHWM "$ndpid") / 1024 ))
    sort -g "$work/nlat" > "$work/nlat.s"
    net_p99=$(pct "$work/nlat.s" 99)
    nlat="$(pct "$work/nlat.s" 50)/$net_p99/$(pct "$work/nlat.s" 100) ms ($(wc -l < "$work/nlat") GETs)"
    still=$(printing)
    echo "octoprint: window ${wall%.*} s, load $load0 -> $load1, $still of $n still printing at the end"
    kill "$ndpid" "$npid"; wait "$ndpid" "$npid" 2>/dev/null
    nlife=$(awk -v a="$nt_start" -v b="$(now)" 'BEGIN { printf "%.0f", b - a }')
    # The simulator's exit stats: requests served per printer over its whole life.
    reqs=$(awk '/^stats: printer=/ { for (i = 1; i <= NF; i++) if ($i ~ /^requests=/) { split($i, kv, "="); s += kv[2] } }
      END { print s + 0 }' "$work/net.err")
    net_row=$(printf '%-20s %7s %8s %6s %18s %9s %9s %8s %s' "slimfarmd octoprint" "$net_cpu" "$net_sim" \
      "$net_rss" "-" "-" "-" "-" "$nlat")
    net_note="(octoprint: daemon peak RSS ${net_hwm} MB; the simulator served $reqs HTTP requests in its $nlife s ($(awk -v r="$reqs" -v s="$nlife" -v n="$n" 'BEGIN { if (s > 0) printf "%.2f", r / s / n; else print "-" }')/s per printer, uploads and polls); CPU ratio network/Marlin $(awk -v a="$net_cpu" -v b="$ours_cpu" 'BEGIN { if (b > 0) printf "%.2f", a / b; else print "-" }'), p99 ratio $(awk -v a="$net_p99" -v b="$o_p99" 'BEGIN { if (b > 0) printf "%.2f", a / b; else print "-" }'))"
  else
    net_row="slimfarmd octoprint: only $got of $n printers printing ($(tail -n 2 "$work/ndaemon.log" | tr '\n' ' '))"
    kill "$ndpid" "$npid"; wait "$ndpid" "$npid" 2>/dev/null
  fi
  export SLIMFARM_URL=http://127.0.0.1:$port
fi

# ---- peer: printcore x N ----
peer_row=
if [ "$peer" = 1 ] && $py -c 'import printrun.printcore' 2> /dev/null; then
  sim_start peer
  cat > "$work/pc.py" <<'PY'
import os, signal, sys, time
from printrun.printcore import printcore
from printrun import gcoder
port, job, mark = sys.argv[1:4]
p = printcore(port, 115200)
t0 = time.time()
while not p.online and time.time() - t0 < 30:
    time.sleep(0.05)
if not p.online:
    sys.exit("printcore: printer never came online")
p.startprint(gcoder.LightGCode([l.rstrip("\n") for l in open(job)]))
open(mark, "w").close()
signal.signal(signal.SIGTERM, lambda *a: os._exit(0))  # printcore's threads would hold sys.exit
while p.printing:
    time.sleep(0.5)
PY
  pc=()
  for ((i = 0; i < n; i++)); do
    [ -f "$work/gcode/p$i.gcode" ] || { echo "bench_farm50: no G-code for p$i"; exit 1; }
    $py "$work/pc.py" "$(sed -n "$((i + 1))p" "$work/peer.out")" "$work/gcode/p$i.gcode" \
      "$work/pc$i.up" 2> "$work/pc$i.err" &
    pc+=($!); pids+=($!)
  done
  for _ in $(seq 600); do [ "$(ls "$work" | grep -c '^pc.*\.up$')" -ge "$n" ] && break; sleep 0.5; done
  up=$(ls "$work" | grep -c '^pc.*\.up$')
  if [ "$up" -ge "$n" ]; then
    sleep "$warm"
    load0=$(cut -d ' ' -f 1-3 /proc/loadavg)
    c0=$(cpu_ticks "${pc[@]}"); s0=$(cpu_ticks "${sim_pids[@]}"); t0=$(now)
    snapshot peer a
    sleep "$secs"
    snapshot peer b
    t1=$(now); c1=$(cpu_ticks "${pc[@]}"); s1=$(cpu_ticks "${sim_pids[@]}")
    load1=$(cut -d ' ' -f 1-3 /proc/loadavg)
    wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }')
    alive=0; for p in "${pc[@]}"; do kill -0 "$p" 2>/dev/null && alive=$((alive + 1)); done
    p_cpu=$(awk -v c=$((c1 - c0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
    p_sim=$(awk -v c=$((s1 - s0)) -v h="$hz" -v w="$wall" 'BEGIN { printf "%.1f", 100 * c / h / w }')
    p_rss=$(( $(rss_kb VmRSS "${pc[@]}") / 1024 ))
    read -r p_lo p_avg p_hi p_st p_hit p_dry < <(window_stats peer "$wall")
    peer_row=$(printf '%-20s %7s %8s %6s %18s %9s %9s %8s %s' "printcore x$n" "$p_cpu" "$p_sim" \
      "$p_rss" "$p_lo/$p_avg/$p_hi" "$p_st" "$p_hit/$n" "$p_dry" "(no API)")
    echo "printcore: window ${wall%.*} s, load $load0 -> $load1, $alive of $n still printing at the end"
  else
    peer_row="printcore x$n: only $up of $n came online ($(tail -n 1 "$work/pc0.err"))"
  fi
  kill "${pc[@]}" "${sim_pids[@]}" 2>/dev/null; wait "${pc[@]}" "${sim_pids[@]}" 2>/dev/null
else
  peer_row="printcore: skipped (BENCH_PEER=0 or printrun-common not installed)"
fi

echo "$n printers, $baud baud, real time (speed 1), $([ "$procs" = 1 ] && echo "$n simulator processes" || echo "one simulator process"); CPU in % of one core over the window"
printf '%-20s %7s %8s %6s %18s %9s %9s %8s %s\n' host "CPU %" "sim CPU%" "RSS MB" \
  "lines/s min/avg/max" starved "printers" "dry s" "GET /api/printers p50/p99/max"
printf '%-20s %7s %8s %6s %18s %9s %9s %8s %s\n' "slimfarmd (1 proc)" "$ours_cpu" "$ours_sim" \
  "$ours_rss" "$o_lo/$o_avg/$o_hi" "$o_st" "$o_hit/$n" "$o_dry" "$lat"
[ -n "$net_row" ] && echo "$net_row"
echo "$peer_row"
[ -n "${net_note:-}" ] && echo "$net_note"
echo "(slimfarmd peak RSS ${ours_hwm} MB; 'starved': times a planner ran dry while the host had lines, summed; 'printers': how many starved at least once)"
