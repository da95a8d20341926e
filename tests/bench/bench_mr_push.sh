#!/usr/bin/env bash
# tests/bench/bench_mr_push.sh BUILD - HTTP requests a Moonraker printer and
# an OctoPrint printer cost their hosts, per second: slimfarmd with one
# simulated Klipper printer and one simulated OctoPrint (poll_ms default:
# 1000) counted over WINDOW_S seconds while idle, then while both print a
# long G-code job; each simulator's request and pushed-message counters are
# read with SIGUSR1 at both ends of the window.  DAEMON=path runs another
# build's slimfarmd against this build's simulators (before/after).
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
start_net op octoprint --speed 2 --api-key opk3y
cp -r config/printers config/materials "$tmp/"
{
  printf '[farm]\nlisten: 127.0.0.1:%s\ndata_dir: %s/data\napi_keys: %s\n' "$port" "$tmp" "$RW"
  printf '[printer mr]\ndriver: moonraker\nurl: %s\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\n' \
    "$(cat "$tmp/mr.addr")"
  printf '[printer op]\ndriver: octoprint\nurl: %s\napi_key: opk3y\nmaterial: PLA\nnozzle_mm: 0.4\nbed_size: 250, 210, 220\n' \
    "$(cat "$tmp/op.addr")"
} > "$tmp/farm.ini"
start_daemon
for p in mr op; do
  wait_for 60 sh -c "'$C' printers | grep -qE '^$p +idle '" || fail "printer $p not idle: $("$C" printers)"
done
sleep 3 # past the start-up's requests
"$C" shapes "$tmp" > /dev/null || fail "shapes"
for phase in idle printing; do
  if [ $phase = printing ]; then
    for p in mr op; do
      j=$(submit "$tmp/frame.stl" --material PLA --printer $p --method none)
      wait_for 300 sh -c "'$C' printers | grep -qE '^$p +printing '" || fail "job $j never printed on $p: $("$C" jobs)"
    done
    sleep 3
  fi
  read -r a pa <<< "$(counts mr)"
  read -r oa opa <<< "$(counts op)"
  sleep "$WINDOW_S"
  read -r b pb <<< "$(counts mr)"
  read -r ob opb <<< "$(counts op)"
  for k in moonraker:$a:$b:${pa:-0}:${pb:-0} octoprint:$oa:$ob:${opa:-0}:${opb:-0}; do
    IFS=: read -r kind r0 r1 m0 m1 <<< "$k"
    printf '%-9s %-8s %4d requests in %d s: %.2f per second; %d messages pushed (%.2f/s)\n' \
      "$kind" $phase $((r1 - r0)) "$WINDOW_S" "$(echo "($r1 - $r0) / $WINDOW_S" | bc -l)" \
      $((m1 - m0)) "$(echo "($m1 - $m0) / $WINDOW_S" | bc -l)"
  done
done
