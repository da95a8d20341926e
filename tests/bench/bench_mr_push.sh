#!/usr/bin/env bash
# tests/bench/bench_mr_push.sh BUILD - HTTP requests a Moonraker printer
# costs its host, per second: slimfarmd with one simulated Klipper printer
# (poll_ms default: 1000) counted over WINDOW_S seconds while idle, then
# while printing a long G-code job; the simulator's request counter is
# read with SIGUSR1 at both ends of the window.  DAEMON=path runs another
# build's slimfarmd against this build's simulator (before/after).
# Prints figures, never fails on them.
set -u
BUILD=${1:-build/rel}
WINDOW_S=${WINDOW_S:-20}
. "$(dirname "$0")/../integ/lib/farm.sh"
. "$(dirname "$0")/../integ/lib/netprint.sh"
D=${DAEMON:-$D}

# counts NAME: the simulator's requests answered and messages pushed so far (its SIGUSR1
# stats line; a simulator without the pushed count says 0)
counts() {
  local before; before=$(grep -c '^stats:' "$tmp/$1.err")
  eval "kill -USR1 \$sim_$1"
  wait_for 10 sh -c "[ \$(grep -c '^stats:' '$tmp/$1.err') -gt $before ]" || fail "no stats from the sim"
  local line; line=$(grep '^stats:' "$tmp/$1.err" | tail -n 1)
  echo "$(echo "$line" | sed -n 's/.*requests=\([0-9]*\).*/\1/p') $(echo "$line" | sed -n 's/.*pushed=\([0-9]*\).*/\1/p')"
}

start_net mr moonraker --speed 2
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer mr]\ndriver: moonraker\nurl: %s\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\n' \
    "$(cat "$tmp/mr.addr")"
} > "$tmp/farm.ini"
start_daemon
wait_for 60 sh -c "'$C' printers | grep -qE '^mr +idle '" || fail "printer not idle: $("$C" printers)"
sleep 3 # past the start-up's requests
for phase in idle printing; do
  if [ $phase = printing ]; then
    "$C" shapes "$tmp" > /dev/null || fail "shapes"
    j=$(submit "$tmp/frame.stl" --material PLA --printer mr --method none)
    wait_for 300 sh -c "'$C' printers | grep -qE '^mr +printing '" || fail "job $j never printed: $("$C" jobs)"
    sleep 3
  fi
  read -r a pa <<< "$(counts mr)"
  sleep "$WINDOW_S"
  read -r b pb <<< "$(counts mr)"
  printf 'moonraker %-8s %4d requests in %d s: %.2f per second; %d messages pushed (%.2f/s)\n' \
    $phase $((b - a)) "$WINDOW_S" "$(echo "($b - $a) / $WINDOW_S" | bc -l)" $((${pb:-0} - ${pa:-0})) \
    "$(echo "(${pb:-0} - ${pa:-0}) / $WINDOW_S" | bc -l)"
done
