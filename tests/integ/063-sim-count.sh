#!/usr/bin/env bash
# 063-sim-count: `slimfarm-sim --count 3` serves three printers from one
# process (the farm benchmark's setup), each a full printer of its own:
# three hosts stream three different jobs at once and each printer's log
# equals its own job; SIGUSR1 prints one stats line per printer without
# stopping, and each counts only its own commands.
. "$(dirname "$0")/lib/marlin.sh"
for i in 0 1 2; do make_job "$TMP/job$i.gcode" $((300 + 200 * i)); done
"$BUILD/bin/slimfarm-sim" marlin --count 3 --baud 1000000 --speed 2000 --advanced-ok \
  --log "$TMP/plog" > "$TMP/sim.out" 2> "$TMP/sim.err" &
SIM_PID=$!
for _ in $(seq 600); do [ "$(wc -l < "$TMP/sim.out")" -ge 3 ] && break; sleep 0.05; done
mapfile -t ports < "$TMP/sim.out"
[ "${#ports[@]}" = 3 ] || { echo "expected 3 addresses, got: ${ports[*]}; $(cat "$TMP/sim.err")"; exit 1; }
[ "${ports[0]}" != "${ports[1]}" ] && [ "${ports[1]}" != "${ports[2]}" ] || { echo "ports shared: ${ports[*]}"; exit 1; }
hosts=()
for i in 0 1 2; do
  "$BUILD/bin/slimfarm" send "$TMP/job$i.gcode" --port "pty:${ports[$i]}" > "$TMP/send$i.out" 2>&1 &
  hosts+=($!)
done
for i in 0 1 2; do wait "${hosts[$i]}" || { echo "send $i failed: $(tail -n 2 "$TMP/send$i.out")"; exit 1; }; done
kill -USR1 "$SIM_PID"
for _ in $(seq 600); do [ "$(grep -c '^stats: printer=' "$TMP/sim.err")" -ge 3 ] && break; sleep 0.05; done
kill -0 "$SIM_PID" || { echo "SIGUSR1 stopped the simulator"; exit 1; }
stop_sim
# Each printer executed its own job: the job's commands plus the host's handshake and probes.
for i in 0 1 2; do
  cp "$TMP/plog.$i" "$TMP/log"
  check_log "$TMP/job$i.gcode" || { echo "printer $i"; exit 1; }
  want=$(commands "$TMP/job$i.gcode" | wc -l)
  got=$(grep -c "^stats: printer=$i .*executed=" "$TMP/sim.err")
  [ "$got" = 2 ] || { echo "printer $i: $got stats lines, want 2 (SIGUSR1 and exit)"; exit 1; }
  ex=$(sed -n "s/^stats: printer=$i executed=\([0-9]*\).*/\1/p" "$TMP/sim.err" | tail -n 1)
  [ "$ex" -ge "$want" ] && [ "$ex" -le $((want + 20)) ] ||
    { echo "printer $i executed $ex, its job has $want commands"; exit 1; }
done
exit 0
