#!/usr/bin/env bash
# bench_jobstart.sh BUILD - how long start_job holds the loop thread on a
# large job, with and without the scan the farm makes when it prepares the
# job (bench_jobstart.c).  The job: the torus sliced by our slicer, repeated
# 26 times (~116 MB, ~3.9 M command lines; start/end sequences repeat, which
# does not matter for reading time).  Also: putting it into the store, by a
# copy on the loop (before) or adopted on the prepare worker (now).
set -u
build=${1:-build/rel}
cli="$build/bin/slimfarm"
[ -x "$cli" ] && [ -x "$build/bench/bench_jobstart" ] || { echo "bench_jobstart: $build not built"; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$cli" shapes "$work/s" > /dev/null && "$cli" slice "$work/s/torus.stl" -o "$work/t.gcode" > /dev/null ||
  { echo "bench_jobstart: cannot slice the torus"; exit 1; }
for _ in $(seq 26); do cat "$work/t.gcode"; done > "$work/big.gcode"
echo "job: $(du -m "$work/big.gcode" | cut -f1) MB, $(wc -l < "$work/big.gcode") lines; $(uptime | sed 's/.*load/load/')"
"$build/bench/bench_jobstart" "$work/big.gcode" "$work/data"
