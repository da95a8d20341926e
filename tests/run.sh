#!/usr/bin/env bash
# tests/run.sh BUILD_DIR [FILTER]
# Runs every unit test program in BUILD_DIR/tests, then the fuzz corpus
# replays and integration tests, and ends with the line CI reads:
#   total: N passed, N failed
# A program that crashes counts all its cases as failed.
set -u
build=${1:?usage: tests/run.sh BUILD_DIR [FILTER]}
filter=${2:-}
pass=0 fail=0 skip=0 failed_progs=()
for prog in "$build"/tests/test_*; do
  [ -x "$prog" ] || continue
  name=$(basename "$prog")
  # only programs whose source still exists (a stale binary from another branch is no test)
  src=tests/unit/$name.c; [[ $name == test_fuzz_* ]] && src=tests/fuzz/fuzz_${name#test_fuzz_}.c
  [ -f "$src" ] || continue
  [ -n "$filter" ] && [[ "$name" != *"$filter"* ]] && continue
  echo "== $name"
  out=$(timeout 600 "$prog" 2>&1); rc=$?  # a hung program fails, never hangs the run
  printf '%s\n' "$out" | grep -v '^ok ' || true
  last=$(printf '%s\n' "$out" | tail -n 1)
  if [[ "$last" =~ ^([0-9]+)\ passed,\ ([0-9]+)\ failed,\ ([0-9]+)\ skipped$ ]]; then
    pass=$((pass + BASH_REMATCH[1])); fail=$((fail + BASH_REMATCH[2])); skip=$((skip + BASH_REMATCH[3]))
    [ "$rc" -ne 0 ] && [ "${BASH_REMATCH[2]}" -eq 0 ] && { fail=$((fail + 1)); failed_progs+=("$name(rc=$rc)"); }
    [ "${BASH_REMATCH[2]}" -ne 0 ] && failed_progs+=("$name")
  else
    n=$("$prog" --count 2>/dev/null || echo 1)
    echo "   $name crashed (rc=$rc): counting its $n cases as failed"
    fail=$((fail + n)); failed_progs+=("$name(crash)")
  fi
done
# libFuzzer smoke runs: a fixed number of mutations per parser (make fuzz runs long).
for fz in build/fuzz/fuzz_*; do
  [ -x "$fz" ] && [ -f "$fz" ] || continue
  name=$(basename "$fz"); name=${name#fuzz_}
  [ -f "tests/fuzz/fuzz_$name.c" ] || continue
  [ -n "$filter" ] && [[ "fuzz_$name" != *"$filter"* ]] && continue
  work=$(mktemp -d); cp -r "tests/fuzz/corpus/$name/." "$work/" 2>/dev/null
  dict=""; [ -f "tests/fuzz/$name.dict" ] && dict="-dict=tests/fuzz/$name.dict"
  if "$fz" -runs="${FUZZ_RUNS:-3000}" -max_len=65536 $dict "$work" >"$work.log" 2>&1; then
    echo "== fuzz $name: $(grep -o 'Done [0-9]* runs' "$work.log" | head -1)"; pass=$((pass + 1))
  else
    echo "== fuzz $name: FAILED"; tail -40 "$work.log"; fail=$((fail + 1)); failed_progs+=("fuzz_$name")
  fi
  rm -rf "$work" "$work.log"
done
for script in tests/integ/*.sh tests/browser/*.sh; do
  [ -f "$script" ] || continue
  name=$(basename "$script" .sh)
  [ -n "$filter" ] && [[ "$name" != *"$filter"* ]] && continue
  echo "== integ $name"
  # a hung scenario fails instead of hanging the run (CI has 90 minutes in all)
  if BUILD="$build" timeout 600 bash "$script"; then pass=$((pass + 1)); else fail=$((fail + 1)); failed_progs+=("integ/$name"); fi
done
[ ${#failed_progs[@]} -gt 0 ] && echo "failed: ${failed_progs[*]}"
echo "total: $pass passed, $fail failed, $skip skipped"
[ "$fail" -eq 0 ]
