#!/usr/bin/env bash
# bench_marlin.sh BUILD - the Marlin driver against slimfarm-sim.
#
# 1. Link use: `slimfarm send` streams a dense job (short G1 moves) with the
#    printer sped up 1000x so only the link limits; prints lines/s, bytes/s
#    and bytes/s as a fraction of the link's byte rate (baud / 10, 8N1),
#    buffer-aware (ADVANCED_OK window) and ping-pong (--window 1), at 115200
#    and 250000 baud.  Bytes are what the host wrote (line numbers and
#    checksums included: they cross the wire too).
# 2. Planner starvation: a dense curved part (concentric circles of 0.25 mm
#    segments at 50 mm/s, 5 ms a move) printed in real time (speed 1); the
#    simulator counts the times its planner ran dry between moves.
# BENCH_LINES=N sets the job size of part 1 (default 2000); BENCH_ONLY=stock runs
# the stock-Marlin rows only; SIM=PATH runs another simulator (before/after);
# BENCH_RT=1 runs the simulator and the hosts under SCHED_FIFO (chrt -f 10, root):
# on a loaded machine the scheduler's wake-up latency, not the link, otherwise
# sets the round trip (each process sleeps almost all the time; a few % CPU).
set -u
build=${1:-build/rel}
sim=${SIM:-$build/bin/slimfarm-sim}
only=${BENCH_ONLY:-}
rt=; [ -n "${BENCH_RT:-}" ] && rt="chrt -f 10"
cli="$build/bin/slimfarm"
[ -x "$sim" ] && [ -x "$cli" ] || { echo "bench_marlin: $build not built"; exit 1; }
lines=${BENCH_LINES:-2000}
work=$(mktemp -d); pid=
trap '[ -n "$pid" ] && kill "$pid" 2>/dev/null; rm -rf "$work"' EXIT

awk -v n="$lines" 'BEGIN { print "G90"; print "M82"; print "G92 E0"; e = 0
  for (i = 0; i < n; i++) { e += 0.0213; a = i * 0.05
    printf "G1 X%.3f Y%.3f E%.5f F%d\n", 100 + 40 * cos(a), 100 + 40 * sin(a), e, 3000 } }' \
  > "$work/dense.gcode"
# Dense curved part: circles from r = 20 mm inwards, 0.25 mm chords, 0.2 mm layers.
awk 'BEGIN { print "G90"; print "M82"; print "G92 E0"; e = 0; z = 0.2; n = 0
  printf "G1 Z%.2f F600\n", z
  for (r = 20; r > 2 && n < 2400; r -= 0.45) {
    k = int(2 * 3.14159265 * r / 0.25)
    for (i = 0; i <= k && n < 2400; i++) { a = 2 * 3.14159265 * i / k; e += 0.0083; n++
      printf "G1 X%.3f Y%.3f E%.5f F3000\n", 100 + r * cos(a), 100 + r * sin(a), e } } }' \
  > "$work/curved.gcode"

start_sim() { # args... -> $port
  $rt "$sim" marlin "$@" > "$work/sim.out" 2> "$work/sim.err" & pid=$!
  for _ in $(seq 50); do [ -s "$work/sim.out" ] && break; sleep 0.05; done
  port=$(head -n 1 "$work/sim.out")
}
stop_sim() { kill "$pid"; wait "$pid" 2>/dev/null; pid=; }
field() { sed -n "s/.*$1=\([^ ]*\).*/\1/p" "$2" | head -n 1; }

[ -n "$only" ] || echo "link use: $lines-line dense job, printer sped up 1000x"
[ -n "$only" ] || printf "%-8s %-13s %9s %9s %9s\n" baud mode lines/s bytes/s "of link"
for baud in 115200 250000; do
  [ -n "$only" ] && break
  for mode in buffer-aware ping-pong; do
    win=0; [ "$mode" = ping-pong ] && win=1
    start_sim --advanced-ok --baud "$baud" --speed 1000
    "$cli" send "$work/dense.gcode" --port "pty:$port" --baud "$baud" --window "$win" \
      > "$work/send.out" 2> "$work/send.err" || echo "  (send failed: $(tail -n 1 "$work/send.err"))"
    stop_sim
    lps=$(field lines_per_s "$work/send.out"); bps=$(field bytes_per_s "$work/send.out")
    printf "%-8s %-13s %9s %9s %8.1f%%\n" "$baud" "$mode" "$lps" "$bps" \
      "$(awk -v b="$bps" -v r="$baud" 'BEGIN { print 100 * b / (r / 10) }')"
  done
done

# 1b. Stock Marlin: no ADVANCED_OK, BUFSIZE 4, a 128-byte RX ring on a UART
# (--uart: bytes that reach a full ring are lost).  Ours with the byte-counted
# window (buffer_lines 4, rx_buffer 128), ours with the window of 2 lines it
# kept before (--window 2), and Printrun's printcore (ping-pong), side by side.
# printcore's rate is the simulator's received bytes over its print time.
echo "link use on stock Marlin (plain ok, BUFSIZE 4, RX 128 on a UART): $lines-line dense job"
printf "%-8s %-22s %9s %9s %9s %8s\n" baud host lines/s bytes/s "of link" dropped
pc_py='import sys, time
from printrun.printcore import printcore
from printrun import gcoder
p = printcore(sys.argv[1], int(sys.argv[3]))
t0 = time.time()
while not p.online and time.time() - t0 < 10:
    time.sleep(0.01)
lines = [l.rstrip("\n") for l in open(sys.argv[2])]
p.startprint(gcoder.LightGCode(lines))
t0 = time.time()
while p.printing and time.time() - t0 < 600:
    time.sleep(0.002)
dt = time.time() - t0
p.disconnect()
print("seconds=%.3f lines_per_s=%.0f" % (dt, len(lines) / dt))'
for baud in 115200 250000; do
  for host in "slimfarm bytes+lines" "slimfarm window 2" printcore; do
    start_sim --baud "$baud" --speed 1000 --uart
    if [ "$host" = printcore ]; then
      if ! /usr/bin/python3 -c 'import printrun.printcore' 2>/dev/null; then
        echo "  (printrun not installed)"; stop_sim; continue
      fi
      $rt /usr/bin/python3 -c "$pc_py" "$port" "$work/dense.gcode" "$baud" > "$work/send.out" 2> "$work/send.err" ||
        echo "  (printcore failed: $(tail -n 1 "$work/send.err"))"
    else
      win=0; [ "$host" = "slimfarm window 2" ] && win=2
      $rt "$cli" send "$work/dense.gcode" --port "pty:$port" --baud "$baud" --window "$win" \
        > "$work/send.out" 2> "$work/send.err" || echo "  (send failed: $(tail -n 1 "$work/send.err"))"
    fi
    stop_sim
    secs=$(field seconds "$work/send.out"); lps=$(field lines_per_s "$work/send.out")
    rx=$(field rx_bytes "$work/sim.err"); dropped=$(field rx_dropped "$work/sim.err")
    if [ "$host" = printcore ]; then
      bps=$(awk -v b="$rx" -v s="$secs" 'BEGIN { printf "%.0f", b / s }')
    else
      bps=$(field bytes_per_s "$work/send.out")
    fi
    printf "%-8s %-22s %9s %9s %8.1f%% %8s\n" "$baud" "$host" "$lps" "$bps" \
      "$(awk -v b="$bps" -v r="$baud" 'BEGIN { print 100 * b / (r / 10) }')" "$dropped"
  done
done

[ -n "$only" ] && exit 0
moves=$(grep -c '^G1 X' "$work/curved.gcode")
echo "planner starvation: dense curved part, $moves moves of 5 ms, real time"
printf "%-8s %-13s %9s %10s %9s\n" baud mode starved "dry (s)" "wall (s)"
for baud in 115200 250000; do
  for mode in buffer-aware ping-pong; do
    win=0; [ "$mode" = ping-pong ] && win=1
    start_sim --advanced-ok --baud "$baud" --speed 1
    "$cli" send "$work/curved.gcode" --port "pty:$port" --baud "$baud" --window "$win" \
      > "$work/send.out" 2> "$work/send.err" || echo "  (send failed: $(tail -n 1 "$work/send.err"))"
    stop_sim
    printf "%-8s %-13s %9s %10s %9s\n" "$baud" "$mode" "$(field starved "$work/sim.err")" \
      "$(field starved_s "$work/sim.err")" "$(field seconds "$work/send.out")"
  done
done
