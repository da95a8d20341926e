#!/usr/bin/env bash
# bench_store_busy.sh BUILD - one print on a simulated Marlin with the
# store's database free, then the same print with another process holding
# SQLite's write lock (tests/integ/farmd_store_busy.sh, BUSY_LOCK=0 and 1),
# side by side: the commands the printer ran in the window (the time the
# simulator took for LINES, default 2000, commands from the moment the lock
# was taken), their rate, and the daemon's longest loop turn over the whole
# print (GET /metrics, slimfarm_loop_turn_max_seconds).  With the store
# thread the rate should not drop under the lock; before it, the printer ran
# 16 commands per 5 s busy timeout (48 in 120 s).
set -u
build=${1:-build/rel}
for b in slimfarmd slimfarm slimfarm-sim; do
  [ -x "$build/bin/$b" ] || { echo "bench_store_busy: $build/bin/$b not built"; exit 1; }
done
printf '%-8s %8s %8s %10s %14s %8s\n' lock lines secs lines/s loop_turn_max retries
for lock in 0 1; do
  out=$(BUILD=$build BUSY_LOCK=$lock bash tests/integ/farmd_store_busy.sh 2>&1)
  w=$(echo "$out" | sed -n 's/^window: //p')
  [ -n "$w" ] || { echo "bench_store_busy: lock=$lock failed: $(echo "$out" | tail -n 5)"; continue; }
  eval "$w" # lock= lines= secs= turn_max_s= retries=
  printf '%-8s %8s %8s %10.0f %12.3f s %8s\n' "$([ "$lock" = 1 ] && echo held || echo free)" \
    "$lines" "$secs" "$(echo "$lines / $secs" | bc -l)" "$turn_max_s" "$retries"
done
