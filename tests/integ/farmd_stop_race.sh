#!/usr/bin/env bash
# tests/integ/farmd_stop_race.sh - printers and the daemon stopping together
# (issue 16): slimfarmd with two simulated printers is frozen (SIGSTOP), gets
# SIGTERM, both printers die, then it is let go: the stop and the drops are
# all pending at once whatever the machine's load, so the drops are handled
# while the daemon tears down (in the loop turns that drain its pool).
# Each of ROUNDS rounds must end with exit 0 and a clean sanitizer log (a
# wake posted by the drop used to run MHD_run on the freed server: exit 139
# in the release build, a use-after-free report under ASan).
set -u
BUILD=${BUILD:-build/san}
. "$(dirname "$0")/lib/farm.sh"
ROUNDS=${ROUNDS:-6}

for round in $(seq "$ROUNDS"); do
  start_sim a
  start_sim b
  {
    printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
    for n in a b; do
      printf '[printer %s]\ndriver: marlin\nport: %s\nbaud: 1000000\n' "$n" "$(cat "$tmp/$n.addr")"
    done
  } > "$tmp/farm.ini"
  : > "$tmp/log"
  start_daemon
  wait_for 20 sh -c "[ \$('$C' printers | grep -c ' idle ') -eq 2 ]" ||
    fail "round $round: printers: $("$C" printers)"
  kill -STOP "$pid"
  kill -TERM "$pid"
  for p in "${sims[@]}"; do kill -9 "$p" 2>/dev/null; wait "$p" 2>/dev/null; done
  sims=()
  kill -CONT "$pid"
  wait "$pid"; rc=$?; pid=
  [ $rc -eq 0 ] || fail "round $round: slimfarmd exited $rc"
  grep -q "Sanitizer" "$tmp/log" && fail "round $round: sanitizer report"
done
echo "farmd_stop_race: ok ($ROUNDS rounds)"
