#!/usr/bin/env bash
# tests/bench/run.sh BUILD - run every benchmark script tests/bench/bench_*.sh.
# Benchmarks print figures; they never fail on time.
# The optimizers and the slicer are reported on every set of parts
# (tests/bench/valsets.sh: shared, the tuning set, and the validation sets
# mech and scad): VALSETS (default all) sets SUPGRAMS_SET and BENCH_SET
# unless they are set themselves, e.g. VALSETS=shared for the tuning set
# alone.
set -u
umask 077 # slimfarmd refuses a config holding keys that others can read
build=${1:-build/rel}
export SUPGRAMS_SET=${SUPGRAMS_SET:-${VALSETS:-all}} BENCH_SET=${BENCH_SET:-${VALSETS:-all}}
for b in tests/bench/bench_*.sh; do
  [ -f "$b" ] || continue
  echo "=== $(basename "$b" .sh)"
  bash "$b" "$build" || echo "($(basename "$b") exited $?)"
done
