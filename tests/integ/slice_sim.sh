#!/usr/bin/env bash
# slice_sim.sh - slice the generated tee (supports on) and stream the G-code
# to the simulated Marlin printer: every line must be acknowledged, no
# halt.  Skips (passes) while the simulator and the send command are not
# in this tree.  Env: BUILD (build dir, e.g. build/san).
set -u
build=${BUILD:-build/rel}
bin="$build/bin/slimfarm" sim="$build/bin/slimfarm-sim"
if [ ! -x "$sim" ] || ! "$bin" help send >/dev/null 2>&1; then
  echo "   skipped: no slimfarm-sim / slimfarm send in $build"
  exit 0
fi
work=$(mktemp -d)
simpid=
cleanup() { [ -n "$simpid" ] && kill "$simpid" 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT
"$bin" shapes "$work" >/dev/null || { echo "shapes failed"; exit 1; }
"$bin" slice "$work/tee.stl" -o "$work/tee.gcode" >/dev/null || { echo "slice failed"; exit 1; }
"$sim" marlin --tcp 0 --speed 100000 --baud 4000000 >"$work/sim.out" 2>"$work/sim.err" &
simpid=$!
for _ in $(seq 300); do [ -s "$work/sim.out" ] && break; sleep 0.1; done
addr=$(head -n 1 "$work/sim.out")
out=$(timeout 300 "$bin" send "$work/tee.gcode" --port "$addr" --window 8 2>&1) || {
  echo "send failed: $(tail -n 3 <<<"$out")"; exit 1; }
kill "$simpid"; wait "$simpid" 2>/dev/null; simpid=
read -r lines acked <<<"$(sed -n 's/^sent: lines=\([0-9]*\) acked=\([0-9]*\).*/\1 \2/p' <<<"$out")"
halted=$(sed -n 's/.*halted=\([0-9]*\).*/\1/p' "$work/sim.err")
if [ -z "${lines:-}" ] || [ "$lines" != "${acked:-}" ] || [ "${halted:-1}" != 0 ]; then
  echo "tee.gcode on the sim: lines=${lines:-?} acked=${acked:-?} halted=${halted:-?}"; exit 1
fi
echo "   tee.gcode: $lines lines acknowledged by the simulated Marlin"
